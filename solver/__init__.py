"""wavebrdf.solver: the numerics (models, kernels' hosts, far fields, metrics).

Importing it sets numpy's huge-page advice as ``NUMPY_MADVISE_HUGEPAGE`` says, else as measured
on this node (:func:`wavebrdf.solver.resources.huge_page_advice`: advised first touches cost
seconds per GiB of system time on nodes that compact memory on fault, and spare the page faults
of large temporaries where huge pages are at hand)."""

from wavebrdf.solver.resources import huge_page_advice as _huge_page_advice

_huge_page_advice()
