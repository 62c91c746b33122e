"""wavebrdf.solver: the numerics (models, kernels' hosts, far fields, metrics).

Importing it switches numpy's huge-page advice off unless ``NUMPY_MADVISE_HUGEPAGE`` is set
(:func:`wavebrdf.solver.resources.huge_page_advice`: first touches of advised pages cost seconds
per GiB of system time on nodes that compact memory on fault)."""

from wavebrdf.solver.resources import huge_page_advice as _huge_page_advice

_huge_page_advice()
