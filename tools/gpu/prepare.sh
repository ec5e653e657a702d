#!/usr/bin/env bash
# Puts tools/gpu/run.sh, the wheels that the device bundle (../shared/gpu/bundle.sh: warp-lang, usd-core,
# trimesh) lacks but warpsph imports (pydantic and its dependencies, h5py; CPython 3.12 manylinux), and
# the commit under .gpu/s/ (git-ignored). Run from the checkout's root after bundle.sh.
set -euo pipefail
root=$(git rev-parse --show-toplevel); cd "$root"
mkdir -p .gpu/s/wheels
cp tools/gpu/run.sh .gpu/s/run.sh
pins=$(python3 - <<'P'
from importlib.metadata import version
print(" ".join(f"{p}=={version(p)}" for p in
      ("pydantic", "pydantic_core", "annotated-types", "typing_extensions", "typing-inspection", "h5py")))
P
)
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d .gpu/s/wheels $pins
git rev-parse --short HEAD > .gpu/s/COMMIT
echo "ready: .gpu/s ($(du -sh .gpu/s | cut -f1)), commit $(cat .gpu/s/COMMIT); wheels: $pins"
