"""Thin wrapper: the job benchmark lives in warpsph/validation/bench_job.py (``warpsph bench job``; see its
docstring). The time to the first step counts from this script's first line."""

import time

T0 = time.perf_counter()

import sys  # noqa: E402

from warpsph.validation.bench_job import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main(t0=T0))
