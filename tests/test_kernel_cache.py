"""The rasterizer kernels' on-disk cache: what is compiled may be loaded by any later process.

Numba (0.68.1) can store a cached ``@njit`` function that calls another cached
one against the callee's code as loaded from the cache; every later process
that loads the caller then crashes (segmentation fault). That happened when
the caller was compiled while the callee came from the cache (reproduced by
deleting the caller's cache files alone; two batch workers compiling at
once on a cold cache can do the same), with the entry points ``activate``
and ``cone_cull``, which were such callers.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from numba.core.registry import CPUDispatcher

from seed2gs_inverse.raster import _kernels

REPO = Path(__file__).resolve().parents[1]


def test_compiled_code_calls_only_inlined_helpers():
    """No compiled kernel calls another compiled function that is not inlined (nor is one an entry point)."""
    for name, fn in vars(_kernels).items():
        if not isinstance(fn, CPUDispatcher):
            continue
        for ref in fn.py_func.__code__.co_names:
            callee = getattr(_kernels, ref, None)
            if isinstance(callee, CPUDispatcher):
                assert callee.targetoptions.get("inline") == "always", f"compiled {name} calls compiled {ref}"
    for kernel in _kernels.ENTRY_KERNELS:
        assert isinstance(kernel, CPUDispatcher) and kernel.targetoptions.get("inline") != "always"


_SCRIPT = """
import numpy as np
from seed2gs_inverse.camera import Camera
from seed2gs_inverse.raster import cone_cull
from seed2gs_inverse.scene import GaussianScene
rng = np.random.default_rng(0)
n = 300
scene = GaussianScene(rng.uniform(-2, 2, (n, 3)), rng.normal(size=(n, 4)), rng.normal(-2.2, 0.6, (n, 3)),
                      rng.normal(1.0, 1.0, n), rng.normal(size=(n, 1, 3)))
cam = Camera.look_at([0.5, -1.0, -5.0], [0, 0, 0], [0, -1, 0], 50, 64, 48)
print(cone_cull(scene, cam, (10, 5, 40, 30)).tolist())
"""


def test_the_cull_kernel_loads_from_any_partial_cache(tmp_path):
    """Compile cold, delete one cached function's files, then run twice: the second process loads what the
    first compiled against the rest of the cache (with the old ``cone_cull`` caller: a segmentation fault)."""
    def run(cache):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(REPO)}
        out = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, f"exit status {out.returncode}: {out.stderr[-2000:]}"
        return out.stdout

    first = run(tmp_path / "probe")
    names = sorted({p.name.split("-")[0] for p in (tmp_path / "probe").rglob("*.nbi")})
    assert any("cone_cull" in n for n in names), names
    for k, name in enumerate(names):
        cache = tmp_path / f"cache{k}"
        assert run(cache) == first  # cold
        for p in cache.rglob(f"{name}-*"):
            p.unlink()
        assert run(cache) == first  # compiled against whatever else is cached
        assert run(cache) == first  # and loaded from the cache
