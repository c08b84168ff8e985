#!/usr/bin/env bash
# igi bench scaling on a bare many-core host from a source tree, without pip access:
# the missing wheels travel in WHEELS (pip download … -d DIR), scenes in SCENES. Used for the
# 16-core scaling runs (docs/scaling.md, "Measured on 16 cores"). Writes OUT/scaling.{json,png}
# and OUT/log.
#   WHEELS=.whl SCENES=.devscenes OUT=/tmp/out bench/remote_scaling.sh [bench scaling flags…]
set -euo pipefail
cd "$(dirname "$0")/.."
: "${WHEELS:=.whl}" "${SCENES:=.devscenes}" "${OUT:=artifacts}"
PY=${PYTHON:-python3}
site=$(mktemp -d)
if compgen -G "$WHEELS/*.whl" >/dev/null; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" "$WHEELS"/*.whl
fi
# The package as installed (igi.common → common/ …), without building it.
mkdir -p "$site/igi"
for p in common worker master bench; do ln -sfn "$PWD/$p" "$site/igi/$p"; done
export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
igi() { $PY -c 'import sys; from igi.master.cli import main; sys.exit(main(sys.argv[1:]))' "$@"; }
mkdir -p "$OUT"
{
    echo "host: $(nproc) cores, $($PY --version), $(uname -r)"
    $PY -c 'import numpy, numba, embreex, zmq; print("numpy", numpy.__version__, "numba", numba.__version__, "zmq", zmq.__version__)'
    # Compile every kernel once into numba's on-disk cache, so no worker compiles in a frame.
    t0=$(date +%s)
    $PY -c 'from igi.worker.kernels.warm import warm_up; warm_up()'
    igi render "$SCENES/cornell-box-sphere/scene.xml" -o "$OUT/warm.png" --workers 0 --frames 2 --width 80 --height 60
    echo "kernels compiled in $(( $(date +%s) - t0 )) s"
    igi bench scaling "$SCENES/cornell-box-sphere/scene.xml" -o "$OUT/scaling" "$@"
} 2>&1 | tee "$OUT/log"
