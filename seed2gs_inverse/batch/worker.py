"""What runs on a worker: one job, with the scene read once per worker process.

:func:`run_job` is the task the batch runner submits, one per job. It never
raises for a bad job: a missing scene file, an unreadable camera or a prompt
outside the image comes back as a ``failed`` :class:`JobResult` with the
message, so one bad job never stops a batch. Only the death of the worker
process itself reaches the runner (which then retries the job once).

Scenes are kept in a small per-process cache keyed by the file's path, size
and modification time, so every job on the same scene that lands on the
same worker reuses the arrays instead of reading the file again (the runner
submits jobs grouped by scene, so each worker meets each scene once). A
models configuration (ONNX sessions) is likewise opened once per process
(:func:`job_models`), not once per job.

A Dask worker imports this module on its event loop, when it unpickles its
first task; so the pipeline (and Numba) are imported inside :func:`run_job`,
in the task's thread, where a slow import holds up no heartbeat.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from collections import OrderedDict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .._memory import peak_rss_mb
from ..errors import FormatError, ValidationError
from ..frontend import config as models_config
from ..io import read_scene
from ..scene import GaussianScene
from .cluster import available_cores

if TYPE_CHECKING:
    from .jobs import Job

__all__ = ["JobResult", "run_job", "job_models", "cached_scene", "scene_cache_info", "clear_scene_cache",
           "SCENE_CACHE_SIZE"]

#: Scenes kept per worker process (least recently used dropped first).
SCENE_CACHE_SIZE = 2

_lock = threading.Lock()
_scenes: OrderedDict[tuple, GaussianScene] = OrderedDict()
# id(scene) -> (scene, its FrozenScene): activations and spatial index made once per cached scene
_frozen: OrderedDict[int, tuple] = OrderedDict()
_reads: list = []          # (path, seconds) of every read by this process
_models: dict = {}         # (path, size, mtime) of a models file -> (grounder, tracker)
_model_loads: list = []    # path of every models file this process opened


@dataclass
class JobResult:
    """Outcome of one job.

    Attributes
    ----------
    name : str
    status : {"done", "failed"}
    error : str or None
        ``"ErrorType: message"`` of a failed job.
    scene : str
        The job's scene file.
    camera : str or dict
        The job's camera as its spec (``FILE[:NAME]``, a look-at table or a camera record).
    prompt : dict
        The prompt's kind and values.
    n_gaussians, n_selected, n_views : int or None
        Scene size, selected Gaussians, supervision views (None when failed early).
    seconds : dict
        Wall time per stage: ``read`` (scene file; 0 when it came from this
        worker's cache), ``camera``, extract's ``render, grounding, lift, vaas,
        tracking, operators, solve`` and ``compile`` (the kernels'
        compilation, which no stage counts: 0 unless the cache was cold),
        and ``write`` (the job folder).
    total_seconds : float
        Wall time of the whole task on the worker.
    worker : str
        The worker's address (``"local"`` when run in this process).
    scene_cached : bool
        The scene came from the worker's cache (no file read).
    attempts : int
        1, or 2 when the job was retried after its worker died.
    peak_rss_mb : float
        Peak resident memory of the worker process so far (MiB; NaN where the platform does not say).
    outdir : str or None
        The job's folder (None without an output directory).
    fingerprint : str
        :meth:`Job.fingerprint`, for resume.
    q : (N,) float32 or None
        Foreground probabilities, kept only when no output directory was
        given (else read them with :meth:`load_q`).
    resumed : bool
        Done by an earlier run and skipped by this one.
    """

    name: str
    status: str
    error: str | None = None
    scene: str = ""
    camera: str | dict | None = None
    prompt: dict = field(default_factory=dict)
    n_gaussians: int | None = None
    n_selected: int | None = None
    n_views: int | None = None
    seconds: dict = field(default_factory=dict)
    total_seconds: float = 0.0
    worker: str = "local"
    scene_cached: bool = False
    attempts: int = 1
    peak_rss_mb: float = 0.0
    outdir: str | None = None
    fingerprint: str = ""
    q: np.ndarray | None = None
    resumed: bool = False

    @property
    def ok(self) -> bool:
        """Whether the job is done."""
        return self.status == "done"

    def load_q(self) -> np.ndarray:
        """``q`` of a done job: kept in memory, else ``q.npy`` of its folder."""
        if self.q is not None:
            return self.q
        if self.outdir is None or self.status != "done":
            raise ValidationError(f"job {self.name!r} has no q ({self.status}"
                                  f"{': ' + self.error if self.error else ''})")
        return np.load(Path(self.outdir) / "q.npy", allow_pickle=False)

    def to_dict(self) -> dict:
        """JSON-ready record (everything but ``q``): one line of ``summary.json``."""
        d = asdict(self)
        d.pop("q")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> JobResult:
        """The result a :meth:`to_dict` record describes (unknown keys are ignored)."""
        known = set(cls.__dataclass_fields__) - {"q"}
        return cls(**{k: v for k, v in d.items() if k in known})


def _worker_name() -> str:
    """The address of the Dask worker running this task, ``"local"`` outside one."""
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return "local"


def _limit_threads() -> None:
    """Numba threads of this task: the cores divided among the worker's task threads.

    An embedded cluster already sets NUMBA_NUM_THREADS per worker process; on
    an external worker with several threads each task would otherwise start
    a parallel region on every core. ``numba.set_num_threads`` is per thread.
    (BLAS is limited to one thread inside ``solve()``.)
    """
    try:
        from distributed import get_worker

        nthreads = max(1, int(get_worker().state.nthreads))
    except (ImportError, ValueError, AttributeError):
        return
    import numba  # deferred: see the module docstring

    cores = available_cores()
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, cores // nthreads)))


def cached_scene(path: str) -> tuple[GaussianScene, float, bool]:
    """``(scene, seconds spent reading, came from the cache)`` of the scene file ``path``.

    Read at most once per process while it stays among the last
    :data:`SCENE_CACHE_SIZE` scenes used; keyed by the file's real path,
    size and modification time, so a rewritten file is read again.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist (naming it).
    FormatError
        As :func:`~seed2gs_inverse.io.read_scene`.
    """
    st = os.stat(path)  # FileNotFoundError names the file
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    with _lock:  # one reader per file at a time; the others wait and reuse it
        if key in _scenes:
            _scenes.move_to_end(key)
            return _scenes[key], 0.0, True
        t0 = time.perf_counter()
        scene = read_scene(path)
        dt = time.perf_counter() - t0
        _reads.append((key[0], dt))
        _scenes[key] = scene
        while len(_scenes) > SCENE_CACHE_SIZE:
            _scenes.popitem(last=False)
        return scene, dt, False


def _frozen_scene(scene: GaussianScene):
    """The :class:`~seed2gs_inverse.raster.FrozenScene` of a cached ``scene``, made once while it stays cached.

    The jobs on one scene then share its activations and spatial index
    (``extract`` visits only the Gaussians near each object).
    """
    from ..raster import FrozenScene  # deferred: see the module docstring

    with _lock:
        entry = _frozen.get(id(scene))
        if entry is None or entry[0] is not scene:
            entry = (scene, FrozenScene(scene))
            _frozen[id(scene)] = entry
        _frozen.move_to_end(id(scene))
        while len(_frozen) > SCENE_CACHE_SIZE:
            _frozen.popitem(last=False)
        return entry[1]


def scene_cache_info() -> dict:
    """This process's scene reads and models loads.

    ``{"reads": [(path, seconds), ...], "cached": [paths], "model_loads": [paths]}``.
    """
    with _lock:
        return {"reads": list(_reads), "cached": [k[0] for k in _scenes], "model_loads": list(_model_loads)}


def clear_scene_cache() -> None:
    """Forget this process's scenes, models and counts (after running jobs in a non-worker process)."""
    with _lock:
        _scenes.clear()
        _frozen.clear()
        _reads.clear()
        _models.clear()
        _model_loads.clear()


def job_models(path):
    """(grounder, tracker) of a models file, opened once per process; (None, None) without.

    Keyed by the file's real path, size and modification time, so an edited
    configuration is opened again. Errors are those of
    :func:`~seed2gs_inverse.frontend.config.load_models` (a ``FormatError``
    naming the file).
    """
    if path is None:
        return None, None
    path = os.fspath(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FormatError(f"{path}: models configuration file not found") from None
    key = (os.path.realpath(path), st.st_size, st.st_mtime_ns)
    with _lock:
        if key not in _models:
            models = models_config.load_models(path)
            _model_loads.append(key[0])
            _models[key] = (models.grounder(), models.tracker())
        return _models[key]


def _error_text(exc: BaseException, job: Job | None = None) -> str:
    """``"ErrorType: first line of the message"``; a missing file is named with its role in ``job``."""
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, FileNotFoundError) and exc.filename:
        roles = {} if job is None else {f: role for role, f in job.input_files().items()}
        role = roles.get(os.fspath(exc.filename))
        msg = f"{role} file not found: {exc.filename}" if role else f"no such file: {exc.filename}"
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def run_job(job: Job, output=None, attempt: int = 1) -> JobResult:
    """Run one job here (on a worker, or in this process) and write its folder.

    Parameters
    ----------
    job : Job
    output : path, optional
        Results directory; the job's folder ``output/<name>`` is written
        atomically by :func:`~seed2gs_inverse.pipeline.save_extraction`
        (replacing an older one). None: nothing is written and ``q`` is
        returned in the result.
    attempt : int
        Which attempt this is (recorded).

    Returns
    -------
    JobResult
        ``failed`` with the error for any exception the job raises.
    """
    from ..pipeline import extract, save_extraction  # deferred: see the module docstring

    t_start = time.perf_counter()
    res = JobResult(name=job.name, status="failed", scene=job.scene, fingerprint=job.fingerprint(),
                    camera=job.to_dict()["camera"], prompt=job.to_dict()["prompt"],
                    worker=_worker_name(), attempts=int(attempt))
    seconds = {"read": 0.0, "camera": 0.0}
    try:
        _limit_threads()
        t0 = time.perf_counter()
        camera = job.read_camera()  # cheap checks first
        seconds["camera"] = time.perf_counter() - t0
        grounder, tracker = job_models(job.models)
        scene, seconds["read"], res.scene_cached = cached_scene(job.scene)
        res.n_gaussians = int(len(scene))
        ex = extract(_frozen_scene(scene), camera, job.prompt, grounder=grounder, tracker=tracker,
                     **job.extract_kwargs())
        seconds.update({k: float(v) for k, v in ex.seconds.items()})
        res.n_selected = int(np.count_nonzero(ex.selected))
        res.n_views = int(len(ex.views))
        t0 = time.perf_counter()
        if output is not None:
            outdir = Path(output) / job.name
            # the report figure is a matplotlib Figure outside pyplot: nothing for a long-lived worker to close
            save_extraction(ex, outdir, job.format, force=True, figure=job.figure,
                            sections={"batch": {"job": job.name, "fingerprint": res.fingerprint}})
            res.outdir = os.fspath(outdir)
        else:
            res.q = np.asarray(ex.q, dtype=np.float32)
        seconds["write"] = time.perf_counter() - t0
        res.status = "done"
    except Exception as exc:  # noqa: BLE001 - every job error is recorded, none stops the batch
        res.error = _error_text(exc, job)
        if os.environ.get("SEED2GS_BATCH_TRACEBACK"):
            traceback.print_exc(file=sys.stderr)
    res.seconds = seconds
    res.total_seconds = time.perf_counter() - t_start
    peak = peak_rss_mb()
    res.peak_rss_mb = float("nan") if peak is None else peak
    return res
