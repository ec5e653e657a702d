#!/usr/bin/env bash
# Runs sweeps and scene probes on a lent CUDA host (developer script for the device tool).
# Here: bash ../shared/gpu/bundle.sh; bash tools/gpu/prepare.sh   (wheels the bundle lacks, the commit)
# There, first calls: carry .gpu/unpack.sh .gpu/SHA256SUMS .gpu/COUNT and one .gpu/partNN each;
# the last part's call (and every later one) also carries .gpu/s and runs:
#   BUDGET=570 bash .gpu/s/run.sh TASK...   (tasks run side by side; all stopped at BUDGET s)
#   sweep:FILE:START:END:WORKERS   cells [START, END) of sweeps/FILE.json into /tmp/o/FILE (same cell ids
#                                  as the whole file: a later call or the whole file skips them)
#   probe:SCENE:FRAMES:METHOD      warpsph run scenes/SCENE.json at scale 1 with solver.method METHOD
#   cmd:...                        any shell line (after unpack)
set -u
t0=$(date +%s)
bash .gpu/unpack.sh || exit 3
export PYTHONPATH=/tmp/gpu-site:$PWD
if [ ! -f /tmp/gpu-site/.wheels ]; then
  for w in .gpu/s/wheels/*.whl; do python -m zipfile -e "$w" /tmp/gpu-site; done && touch /tmp/gpu-site/.wheels
fi
[ -e warpsph/kernels ] || ln -s ../kernels warpsph/kernels
python -c "import warpsph.simulation, warpsph.sweep, h5py, pydantic" || exit 4
export WARP_CACHE_PATH=/tmp/warpcache
C=$(cat .gpu/s/COMMIT); export WARPSPH_COMMIT=$C; O=/tmp/o; mkdir -p $O; rm -f $O/*.log
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee $O/device.txt
python -c "import warp; print('warp', warp.__version__)" | tee -a $O/device.txt
echo "commit $C" >> $O/device.txt
left=$(( ${BUDGET:-575} - ($(date +%s) - t0) ))
pids=()
for task in "$@"; do
  IFS=: read -r kind a b c d <<<"$task"
  case $kind in
    sweep)
      python - "$a" "$b" "$c" <<'P'
import json, sys
name, s, e = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
d = json.load(open(f"sweeps/{name}.json")); d["cells"] = d["cells"][s:e]
json.dump(d, open(f"sweeps/_{name}_{s}_{e}.json", "w"), indent=1)
P
      ( timeout $left python -m warpsph sweep sweeps/_${a}_${b}_${c}.json --out $O/$a --workers $d \
          > $O/sweep_${a}_${b}_${c}.log 2>&1; echo "rc $?" >> $O/sweep_${a}_${b}_${c}.log ) &
      pids+=($!) ;;
    probe)
      python - "$a" "$c" <<'P'
import json, sys
d = json.load(open(f"scenes/{sys.argv[1]}.json")); d.setdefault("solver", {})["method"] = sys.argv[2]
json.dump(d, open(f"scenes/_probe_{sys.argv[1]}_{sys.argv[2]}.json", "w"), indent=1)
P
      ( cd scenes && timeout $left python -m warpsph run _probe_${a}_${c}.json --scale 1 --device cuda --frames $b \
          --fields points --out $O/probe_${a}_${c}.usdc --overwrite -v > $O/probe_${a}_${c}.log 2>&1
        echo "rc $?" >> $O/probe_${a}_${c}.log; rm -f $O/probe_${a}_${c}.usdc ) &
      pids+=($!) ;;
    cmd)
      ( timeout $left bash -c "${task#cmd:}" > $O/cmd_$(date +%s%N).log 2>&1 ) &
      pids+=($!) ;;
  esac
done
while sleep 30; do
  n=0; for p in "${pids[@]}"; do kill -0 $p 2>/dev/null && n=$((n+1)); done
  echo "$(( $(date +%s) - t0 )) s: $n running; cells done: $(ls $O/*/cells 2>/dev/null | grep -c json)"
  [ $n -eq 0 ] && break
done
tar -C /tmp -czf $OUT/results.tgz o  # every call returns all results so far
tail -n 5 $O/*.log
