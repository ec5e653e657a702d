"""The CUDA build of :mod:`reductions`' kernels: one atomic per block of the threads' partial results, through
Warp's tile sums. Its own Warp module, so that only a CUDA run compiles tile code (:func:`reductions.for_device`)."""

from .reductions import reduction_kernels

DEVICES = ("cuda",)  # the build compiled for these devices (warpsph.warmup)

kernels = reduction_kernels(per_block=True, module=__name__)
