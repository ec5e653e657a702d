#!/usr/bin/env bash
# Strong scaling of one simulation over MPI ranks, one GPU each (#40), against the threads backend in one process.
# On a lent GPU host, at the checkout's root, with PYTHONPATH=/tmp/gpu-site:$PWD (the bundle unpacked, mpi4py and
# the mpich wheel among its wheels, and prepare.sh's wheels: pydantic) and $OUT set:
#   bash tools/gpu/mpi_scaling.sh
# or through tools/gpu/run.sh, which unpacks all that first (results in $OUT/results.tgz):
#   BUDGET=570 bash .gpu/s/run.sh "cmd:OUT=/tmp/o/mpi_scaling bash tools/gpu/mpi_scaling.sh"
# For N in RANKS (default 1 2, and 4 where nvidia-smi lists 4 GPUs or more): the dam break at ~PARTICLES fluid
# particles, plain DFSPH, WARMUP steps then STEPS timed (python -m warpsph.distributed --bench-json) into
# $OUT/mpi_N.json (MPI=0: not run); with THREADS=1 (default) also `warpsph bench steps` (N = 1: one GPU, one
# simulation; else --devices N) into $OUT/threads_N.json. One line a run ($OUT/summary.txt), logs in $OUT/*.log; each
# run stopped after RUN_TIMEOUT s. On the CPU (no nvidia-smi: DEVICE=cpu):
#   PARTICLES=4000 WARMUP=3 STEPS=5 OUT=/tmp/mpi_scaling bash tools/gpu/mpi_scaling.sh
# mpiexec: $MPIEXEC, else the mpich wheel's (unpacked into a PYTHONPATH folder: mpich-*.data/data/bin, made
# executable here, its lib/ put on LD_LIBRARY_PATH for mpi4py; or installed beside python), else PATH's. Hydra
# starts the ranks with -launcher fork (this host only, no ssh).
set -u
PARTICLES=${PARTICLES:-32e6}; WARMUP=${WARMUP:-60}; STEPS=${STEPS:-30}; MODEL=${MODEL:-none}
SCENE=${SCENE:-scenes/dam_break.json}; MPI=${MPI:-1}; THREADS=${THREADS:-1}; RUN_TIMEOUT=${RUN_TIMEOUT:-240}
OUT=${OUT:-out/mpi_scaling}; PY=${PYTHON:-$(command -v python || command -v python3)}
mkdir -p "$OUT"
[ -e warpsph/kernels ] || ln -s ../kernels warpsph/kernels  # the package's kernels/ where it is not installed
gpus=$( (nvidia-smi -L 2>/dev/null || true) | grep -c '^GPU')
DEVICE=${DEVICE:-$([ "$gpus" -gt 0 ] && echo cuda || echo cpu)}
RANKS=${RANKS:-$([ "$gpus" -ge 4 ] && echo "1 2 4" || echo "1 2")}
export WARPSPH_COMMIT=${WARPSPH_COMMIT:-$(git rev-parse --short HEAD 2>/dev/null)}
export MPIR_CVAR_ENABLE_GPU=0  # host buffers only: MPICH need not inspect pointers for device memory

read -r MPIEXEC MPILIB <<<"$("$PY" - <<'P'
import glob, os, shutil, sys
if os.environ.get("MPIEXEC"):
    print(os.environ["MPIEXEC"], "-"); sys.exit()
for folder in filter(None, sys.path):  # the wheel unpacked (python -m zipfile -e: no executable bits)
    for data in glob.glob(os.path.join(folder, "mpich-*.data", "data")):
        print(os.path.join(data, "bin", "mpiexec"), os.path.join(data, "lib")); sys.exit()
beside = os.path.join(os.path.dirname(sys.executable), "mpiexec")  # the wheel installed: a venv's bin/
print(beside if os.path.exists(beside) else shutil.which("mpiexec") or "none", "-")
P
)"
if [ "$MPILIB" != - ]; then
  chmod +x "$(dirname "$MPIEXEC")"/* 2>/dev/null
  export LD_LIBRARY_PATH=$MPILIB${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
fi
[ -x "$MPIEXEC" ] || { echo "no mpiexec ($MPIEXEC): set MPIEXEC"; exit 3; }
"$PY" -c "import warpsph.distributed, mpi4py.MPI" || { echo "warpsph.distributed or mpi4py does not import (above)"; exit 4; }
MPIRUN=("$MPIEXEC" -launcher fork)
{ echo "commit $WARPSPH_COMMIT; $gpus GPUs; device $DEVICE; ranks $RANKS; mpiexec $MPIEXEC"
  (nvidia-smi --query-gpu=index,name,driver_version,memory.total --format=csv,noheader; nvidia-smi topo -m) 2>/dev/null
} | tee "$OUT/host.txt"
"${MPIRUN[@]}" -n 2 "$PY" -c "from mpi4py import MPI; c = MPI.COMM_WORLD; v = MPI.Get_library_version().split()
hosts = c.gather(MPI.Get_processor_name())
c.rank or print(f'mpi4py {v[0]} {v[2]}: {c.size} ranks on {hosts}', flush=True)" 2>&1 | tee -a "$OUT/host.txt"
[ "${PIPESTATUS[0]}" = 0 ] || { echo "mpiexec -n 2 failed (above)"; exit 5; }

line() {  # one line from a result JSON: particles, ms a step, MPI: each rank's ms a step in the communicator; the run's s
  "$PY" - "$@" <<'P'
import json, sys
label, path, wall = sys.argv[1:4]
try:
    r = json.load(open(path))
except (OSError, ValueError) as exc:
    print(f"{label}: no result ({exc}; {wall} s)"); sys.exit()
devices = ",".join(r.get("device_aliases") or [r.get("device", "?")])
text = f"{label}: {r['fluid_particles']:,} particles, {r['ms_per_step']:.1f} ms/step on {devices}"
steps = r.get("timed_steps")
for rank, seconds in enumerate(r.get("comm_seconds_per_rank", [])):
    text += f"; rank {rank} comm ms/step " + " ".join(f"{k} {1e3 * v / steps:.1f}" for k, v in seconds.items())
print(f"{text} ({wall} s)", flush=True)
P
}

common=(--particles "$PARTICLES" --model "$MODEL" --warmup "$WARMUP" --steps "$STEPS")
for n in $([ "$MPI" = 1 ] && echo "$RANKS"); do
  start=$SECONDS
  timeout -k 20 "$RUN_TIMEOUT" "${MPIRUN[@]}" -n "$n" "$PY" -m warpsph.distributed "$SCENE" "${common[@]}" -q \
    --device "$DEVICE" --bench-json "$OUT/mpi_$n.json" > "$OUT/mpi_$n.log" 2>&1
  echo "rc $?" >> "$OUT/mpi_$n.log"
  line "mpi $n" "$OUT/mpi_$n.json" $((SECONDS - start)) | tee -a "$OUT/summary.txt"
done
if [ "$THREADS" = 1 ]; then
  for n in $RANKS; do
    start=$SECONDS
    if [ "$n" = 1 ]; then where=(--device "$([ "$DEVICE" = cuda ] && echo cuda:0 || echo "$DEVICE")")
    elif [ "$DEVICE" = cuda ]; then where=(--devices "$n")
    else where=(--device "$DEVICE" --devices "$DEVICE" --subdomains "$n"); fi
    timeout -k 20 "$RUN_TIMEOUT" "$PY" -m warpsph bench steps --scene "$SCENE" "${common[@]}" "${where[@]}" \
      --out "$OUT/threads_$n.json" > "$OUT/threads_$n.log" 2>&1
    echo "rc $?" >> "$OUT/threads_$n.log"
    line "threads $n" "$OUT/threads_$n.json" $((SECONDS - start)) | tee -a "$OUT/summary.txt"
  done
fi
