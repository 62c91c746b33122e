/* Rooftop index spaces of the near-field pattern (solver/bem3d/mesh.py, aim/nearfield.py).
 *
 * Orientation 0 (horizontal, x-directed): rooftop (x, y), x in [0, N-2], y in [0, N-1],
 *   geometric index g = (N-1) y + x.
 * Orientation 1 (vertical, y-directed): rooftop (x, y), x in [0, N-1], y in [0, N-2],
 *   geometric index g = N (N-1) + (N-1) x + y.
 * "row" = g minus the first index of the orientation (the position inside its block).
 */
#ifndef NEAR_INDEX_H
#define NEAR_INDEX_H

inline int near_valid(int o, int N, int x, int y)
{
    return o == 0 ? (x >= 0 && x <= N - 2 && y >= 0 && y <= N - 1)
                  : (x >= 0 && x <= N - 1 && y >= 0 && y <= N - 2);
}
inline int near_row(int o, int N, int x, int y) { return o == 0 ? (N - 1) * y + x : (N - 1) * x + y; }
inline int near_first(int o, int N) { return o == 0 ? 0 : N * (N - 1); }
inline int2 near_coords(int o, int N, int row)
{
    return o == 0 ? (int2)(row % (N - 1), row / (N - 1)) : (int2)(row / (N - 1), row % (N - 1));
}

#endif
