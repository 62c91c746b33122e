/* The projected-hemisphere output grid (ARCHITECTURE.md conventions): pixel (i, j) of a
 * res x res image has direction cosines u = 2(i + 1/2)/res - 1 (x, rows) and v likewise
 * (y, columns); mu_o = sqrt(1 - u^2 - v^2) inside the unit disk. solver/farfield.py HemisphereGrid
 * is the host twin. */
#ifndef WB_HEMISPHERE_H
#define WB_HEMISPHERE_H
#include "wb_types.h"

/* Direction cosine of pixel index i on a grid of side res. */
inline real_t pixel_coordinate(int i, int res) { return R(2.0) * ((real_t)i + R(0.5)) / (real_t)res - R(1.0); }

#endif
