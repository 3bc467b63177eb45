"""ONNX Runtime sessions with signature checks, shared by every model wrapper.

A *layout* is the list of input and output tensors (name, element types,
rank, fixed sizes) that one public export of a model produces. Opening a
file checks it against the layouts a role accepts and turns every failure
(missing file, corrupt bytes, wrong names, ranks or dtypes) into a
:class:`~seed2gs_inverse.errors.FormatError` that names the file and shows
the expected and the found signature; onnxruntime exceptions never escape.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .._extras import missing_extra
from ..errors import FormatError

__all__ = ["Port", "Layout", "OnnxModel", "format_ports", "onnxruntime_module", "MAX_FIXED_DIM"]

#: Largest fixed input size accepted on any axis of a model's input. The
#: toolkit feeds inputs of the sizes a file fixes (an image resized to its
#: side, zero masks and language features of its shapes); the supported
#: exports fix at most 1333 pixels a side and 1024 features, and a 4096 x
#: 4096 RGB float32 input is 192 MiB, while a file claiming 65536 would make
#: every call allocate 48 GiB.
MAX_FIXED_DIM = 4096

# onnxruntime's type strings and the numpy dtype each one is fed with.
_ORT_TO_NUMPY = {
    "tensor(float)": np.float32,
    "tensor(float16)": np.float16,
    "tensor(double)": np.float64,
    "tensor(int64)": np.int64,
    "tensor(int32)": np.int32,
    "tensor(uint8)": np.uint8,
    "tensor(int8)": np.int8,
    "tensor(bool)": np.bool_,
}
_SHORT = {"tensor(float)": "float32", "tensor(float16)": "float16",
          "tensor(double)": "float64", "tensor(int64)": "int64",
          "tensor(int32)": "int32", "tensor(uint8)": "uint8", "tensor(int8)": "int8",
          "tensor(bool)": "bool"}


@dataclass(frozen=True)
class Port:
    """One expected input or output tensor of a layout.

    Parameters
    ----------
    name : str
        Tensor name in the ONNX graph.
    dtypes : tuple of str
        Accepted element types (``"float32"``, ``"int64"``, ``"bool"``...).
        Inputs are cast to the type the file declares, so variants of one
        export that differ only in an integer width are all accepted.
    rank : int or None
        Number of dimensions; None accepts any rank.
    dims : tuple or None
        Required sizes per axis (None = any). Checked only where the file
        declares a fixed size, since dynamic axes match anything.
    optional : bool
        The layout works without it (it is fed or read only when present).
    """

    name: str
    dtypes: tuple = ("float32",)
    rank: int | None = None
    dims: tuple | None = None
    optional: bool = False

    def describe(self) -> str:
        """``name:dtype|dtype[d0,d1,...]`` as in the error messages (``*`` = any size)."""
        shape = "?" if self.rank is None else (
            "[" + ",".join("*" if d is None else str(d)
                           for d in (self.dims or (None,) * self.rank)) + "]")
        opt = " (optional)" if self.optional else ""
        return f"{self.name}:{'|'.join(self.dtypes)}{shape}{opt}"


@dataclass(frozen=True)
class Layout:
    """Named input/output signature of one supported export."""

    name: str
    inputs: tuple
    outputs: tuple

    def describe(self) -> str:
        """``name: inputs (...) -> outputs (...)`` as in the error messages."""
        return (f"{self.name}: inputs ({', '.join(p.describe() for p in self.inputs)}) "
                f"-> outputs ({', '.join(p.describe() for p in self.outputs)})")


def onnxruntime_module(purpose: str):
    """The ``onnxruntime`` module, imported on first use (large to load; only model files need it).

    Parameters
    ----------
    purpose : str
        What needs it, for the error message.

    Raises
    ------
    MissingExtraError
        onnxruntime cannot be imported; the message names ``pip install "seed2gs-inverse[models]"``.
    """
    try:
        import onnxruntime
    except ImportError as exc:
        raise missing_extra("models", purpose, exc) from None
    return onnxruntime


def _arg_describe(arg) -> str:
    """``name:dtype[shape]`` of one onnxruntime NodeArg (``*`` for a dynamic axis)."""
    shape = "[" + ",".join(str(d) if isinstance(d, int) else "*" for d in (arg.shape or [])) + "]"
    return f"{arg.name}:{_SHORT.get(arg.type, arg.type)}{shape}"


def format_ports(args) -> str:
    """``name:dtype[shape]`` list of onnxruntime NodeArgs (found signature)."""
    return ", ".join(_arg_describe(a) for a in args)


def _mismatch(port: Port, arg) -> str | None:
    """Why the file's NodeArg ``arg`` does not satisfy ``port`` (None if it does)."""
    found = _SHORT.get(arg.type, arg.type)
    if found not in port.dtypes:
        return f"{port.name} has dtype {found}, expected {'|'.join(port.dtypes)}"
    shape = arg.shape
    if port.rank is not None and shape is not None and len(shape) != port.rank:
        return f"{port.name} has rank {len(shape)}, expected {port.rank}"
    if port.dims is not None and shape is not None:
        for axis, (want, got) in enumerate(zip(port.dims, shape)):
            if want is not None and isinstance(got, int) and got > 0 and got != want:
                return f"{port.name} axis {axis} has size {got}, expected {want}"
    return None


def _check_fixed_sizes(path, role: str, inputs) -> None:
    """FormatError naming the file and the limit when an input fixes an axis above :data:`MAX_FIXED_DIM`."""
    for arg in inputs:
        for axis, d in enumerate(arg.shape or []):
            if isinstance(d, int) and d > MAX_FIXED_DIM:
                raise FormatError(f"{path}: input {arg.name} of the {role} model fixes axis {axis} at {d}, "
                                  f"above the limit of {MAX_FIXED_DIM} (the toolkit allocates inputs of the "
                                  "sizes a file fixes); a corrupt or hostile file")


def _check(session, layout: Layout) -> list[str]:
    """Problems of ``session`` against ``layout`` (empty when it matches)."""
    problems = []
    for kind, ports, args in (("input", layout.inputs, session.get_inputs()),
                              ("output", layout.outputs, session.get_outputs())):
        found = {a.name: a for a in args}
        for port in ports:
            if port.name not in found:
                if not port.optional:
                    problems.append(f"missing {kind} {port.name}")
                continue
            why = _mismatch(port, found[port.name])
            if why:
                problems.append(why)
        if kind == "input":  # extra outputs are harmless; an extra input would go unfed
            known = {p.name for p in ports}
            problems += [f"unexpected input {name}" for name in found if name not in known]
    return problems


class OnnxModel:
    """An onnxruntime session whose signature matched one accepted layout.

    Parameters
    ----------
    path : str or Path
        The ONNX file.
    role : str
        What the file is for, used in messages (``"sam2.encoder"``).
    layouts : sequence of Layout
        Accepted layouts; the first one that matches is used (``.layout``).
    providers : sequence of str, optional
        onnxruntime execution providers; default CPU.

    Raises
    ------
    FormatError
        The file is missing, unreadable, not a valid ONNX model, fixes an
        input axis above :data:`MAX_FIXED_DIM`, or matches none of the
        layouts; the message names the file, the expected layout(s) and the
        found signature (or the limit).
    """

    def __init__(self, path, role: str, layouts: Sequence[Layout], providers=None):
        self.path = Path(path)
        self.role = role
        if self.path.exists() and not self.path.is_file():
            raise FormatError(f"{self.path}: not a regular file (a directory, pipe or device); give the ONNX "
                              f"file for {role} in the models configuration")
        if not self.path.is_file():
            raise FormatError(f"{self.path}: ONNX file for {role} not found "
                              "(check the path in the models configuration)")
        ort = onnxruntime_module(f"opening the ONNX model for {role}")
        opts = ort.SessionOptions()
        opts.log_severity_level = 3  # our own messages replace onnxruntime's warnings
        try:
            self.session = ort.InferenceSession(
                str(self.path), opts, providers=list(providers or ["CPUExecutionProvider"]))
        except Exception as exc:  # onnxruntime raises its own pybind exception types
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise FormatError(f"{self.path}: cannot load the ONNX model for {role}: {first}") from None
        _check_fixed_sizes(self.path, role, self.session.get_inputs())
        reports = []
        for layout in layouts:
            problems = _check(self.session, layout)
            if not problems:
                self.layout = layout
                break
            reports.append(f"{layout.describe()} [{'; '.join(problems)}]")
        else:
            raise FormatError(
                f"{self.path}: the ONNX signature does not match {role}; expected "
                + " or ".join(reports)
                + f"; found inputs ({format_ports(self.session.get_inputs())}) -> "
                f"outputs ({format_ports(self.session.get_outputs())})")
        self._inputs = {a.name: a for a in self.session.get_inputs()}
        self._outputs = [a.name for a in self.session.get_outputs()]

    def has_input(self, name: str) -> bool:
        """Whether the file declares the input ``name`` (optional ports may be absent)."""
        return name in self._inputs

    def has_output(self, name: str) -> bool:
        """Whether the file declares the output ``name``."""
        return name in self._outputs

    def input_dim(self, name: str, axis: int, default: int | None = None) -> int | None:
        """Fixed size of ``axis`` of input ``name`` (at most :data:`MAX_FIXED_DIM`), or ``default`` when dynamic."""
        shape = self._inputs[name].shape
        if shape is None or axis >= len(shape) or not isinstance(shape[axis], int) or shape[axis] <= 0:
            return default
        return int(shape[axis])

    def input_dtype(self, name: str):
        """The numpy dtype input ``name`` is fed with (its declared type; float32 if unknown)."""
        return _ORT_TO_NUMPY.get(self._inputs[name].type, np.float32)

    def run(self, feeds: Mapping[str, np.ndarray], outputs: Sequence[str] | None = None) -> dict:
        """Run the model; feeds are cast to the declared dtypes, unknown names dropped.

        Returns a dict of output name -> array. A failure inside onnxruntime
        (shape mismatch in the graph...) is a FormatError naming the file.
        """
        cast = {name: np.ascontiguousarray(np.asarray(v), dtype=self.input_dtype(name))
                for name, v in feeds.items() if name in self._inputs}
        missing = [n for n in self._inputs if n not in cast]
        if missing:
            raise FormatError(f"{self.path}: {self.role} needs inputs {missing} that this "
                              "toolkit does not provide; use one of the documented layouts")
        names = [n for n in (outputs or self._outputs) if n in self._outputs]
        try:
            values = self.session.run(names, cast)
        except Exception as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            shapes = ", ".join(f"{k}{list(v.shape)}" for k, v in cast.items())
            raise FormatError(f"{self.path}: {self.role} failed at run time with inputs "
                              f"({shapes}): {first}") from None
        return dict(zip(names, values))
