#!/usr/bin/env bash
# Conformance harness of the ONNX front end (docs/models.md, "Conformance").
#
#   bash tools/conformance/run.sh [WORK]      (default WORK = tools/conformance/work)
#
# 1. installs the export toolchain (torch, sam2, segment-anything, samexporter,
#    transformers, ...) into ITS OWN virtual environment tools/conformance/.venv
#    (never the project's), pinned in tools/conformance/requirements.txt;
# 2. renders the procedural scene with the project's Python ($PYTHON, default
#    the python on PATH; it must import seed2gs_inverse from this checkout);
# 3. builds every family with random weights, exports it with the exporter we
#    document and records the torch reference outputs (toolchain venv);
# 4. loads every graph through seed2gs_inverse.frontend, compares, and runs
#    `seed2gs models`, grounding, a 5-frame track and `seed2gs extract --prompt`.
# Needs no GPU and no download other than PyPI; about 20-30 minutes on 2 cores.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
WORK="$(realpath -m "${1:-$HERE/work}")"
PY="${PYTHON:-python}"
VENV="${CONFORMANCE_VENV:-$HERE/.venv}"
mkdir -p "$WORK"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --upgrade pip wheel setuptools
"$VENV/bin/pip" install -q -r "$HERE/requirements.txt"
# sam2's sdist builds a CUDA extension it does not need here: build it against
# the torch just installed, without the extension
SAM2_BUILD_CUDA=0 SAM2_BUILD_ALLOW_ERRORS=1 "$VENV/bin/pip" install -q --no-build-isolation "sam2==1.1.0"
cd "$ROOT"
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
"$PY" "$HERE/scene.py" "$WORK"
"$VENV/bin/python" "$HERE/export.py" "$WORK"
"$PY" "$HERE/check.py" "$WORK" | tee "$WORK/summary.txt"
