"""Standard 3DGS PLY files: a small PLY parser and the trainer's layout.

A 3DGS PLY file has one ``vertex`` element with one row per Gaussian:

=====================================  ========================================
properties                             meaning
=====================================  ========================================
``x y z``                              mean
``nx ny nz`` (optional)                normals; the trainer writes zeros
``f_dc_0..2``                          SH DC coefficient per channel
``f_rest_0..3(K-1)-1`` (optional)      higher SH bands, channel-major: all R
                                       coefficients, then all G, then all B
``opacity``                            opacity logit
``scale_0..2``                         log scales
``rot_0..3``                           quaternion, w first
anything else                          kept in ``scene.extra``
=====================================  ========================================

so ``sh[:, 0, c] = f_dc_c`` and ``sh[:, 1 + k, c] = f_rest_{c (K-1) + k}``.

Reading accepts ASCII, binary little- and big-endian files, any property
order and any numeric property type (values are converted to float32).
Normals are put in ``extra`` unless every normal component is zero (the
trainer's zeros carry no information, so no array is kept for them). The
file's property names and types are kept as ``scene.layout``.

Writing always produces binary little-endian. A scene that still fits the
layout it was read with is written with the same properties, order and
types (zeros for normals the file held as zeros), so an unmodified scene or
a subset of it has the input's header. Any other scene is written as
float32 in the trainer's order, normals included (zeros unless ``extra``
holds them), followed by the extra properties in their own dtypes.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ValidationError
from ._common import atomic_write, fail, file_size, finish_scene, warn_caller, warn_trailing

if TYPE_CHECKING:
    from ..scene import GaussianScene

__all__ = ["PlyHeader", "PlyElement", "read_ply_header", "read_ply_elements",
           "read_standard_ply", "write_standard_ply", "ply_field_names"]

# PLY scalar type names (both spellings) -> numpy type codes without byte order.
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
          "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
          "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
# numpy type codes -> the names the 3DGS trainer (and plyfile) write.
_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort",
          "i4": "int", "u4": "uint", "f4": "float", "f8": "double"}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}

_MAX_HEADER_BYTES = 1 << 20
_NAME_RE = re.compile(r"^[^\s]+$")


@dataclass
class PlyElement:
    """One ``element`` of a PLY header."""

    name: str
    count: int
    properties: list = field(default_factory=list)  # [(name, numpy code)]
    lists: list = field(default_factory=list)       # names of list properties

    def dtype(self, order: str) -> np.dtype:
        return np.dtype([(n, order + c) for n, c in self.properties])

    @property
    def names(self) -> list:
        return [n for n, _ in self.properties]


@dataclass
class PlyHeader:
    """A parsed PLY header; ``data_offset`` is where the body starts."""

    format: str
    elements: list
    data_offset: int

    def element(self, name: str) -> PlyElement | None:
        for el in self.elements:
            if el.name == name:
                return el
        return None


def read_ply_header(path) -> PlyHeader:
    """Parse the header of a PLY file (at most 1 MiB of header text).

    Raises FormatError naming the file for a missing magic, an unknown format
    or type, a malformed count, duplicate names or a missing ``end_header``.
    """
    elements: list[PlyElement] = []
    fmt = None
    with open(path, "rb") as fh:
        first = fh.readline(16)
        if first.rstrip(b"\r\n") != b"ply":
            # name what it looks like instead, when its magic bytes say so
            hint = ("; it starts like an SPZ file (gzip or 'NGSP'): if it is one, rename it .spz"
                    if first[:2] == b"\x1f\x8b" or first[:4] == b"NGSP" else "")
            raise fail(path, f"not a PLY file (it does not start with the 'ply' magic line){hint}")
        total = len(first)
        while True:
            raw = fh.readline(_MAX_HEADER_BYTES)
            total += len(raw)
            if not raw or total > _MAX_HEADER_BYTES:
                raise fail(path, "PLY header has no 'end_header' line (truncated or not a PLY file)")
            try:
                line = raw.decode("ascii").strip()
            except UnicodeDecodeError:
                raise fail(path, "PLY header contains non-ASCII bytes (corrupt header)") from None
            words = line.split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            key = words[0]
            if key == "end_header":
                break
            if key == "format":
                if len(words) != 3 or words[1] not in _FORMATS:
                    raise fail(path, f"unsupported PLY format line '{line}' (expected ascii, "
                                     f"binary_little_endian or binary_big_endian)")
                if words[2] != "1.0":
                    raise fail(path, f"unsupported PLY version '{words[2]}' (expected 1.0)")
                fmt = words[1]
            elif key == "element":
                # ASCII digits only: str.isdigit() accepts '²', and a 5000-digit count
                # would make int() raise
                if len(words) != 3 or not re.fullmatch(r"[0-9]{1,19}", words[2]):
                    raise fail(path, f"malformed PLY element line '{line[:80]}' "
                                     f"(expected 'element NAME COUNT' with COUNT below 10^19)")
                if any(el.name == words[1] for el in elements):
                    raise fail(path, f"PLY header declares element '{words[1]}' twice")
                elements.append(PlyElement(words[1], int(words[2])))
            elif key == "property":
                if not elements:
                    raise fail(path, f"PLY property before any element: '{line}'")
                el = elements[-1]
                if len(words) == 5 and words[1] == "list":
                    if words[2] not in _TYPES or words[3] not in _TYPES:
                        raise fail(path, f"unknown PLY type in '{line}'")
                    name, code = words[4], None
                elif len(words) == 3:
                    if words[1] not in _TYPES:
                        raise fail(path, f"unknown PLY property type '{words[1]}' in '{line}'")
                    name, code = words[2], _TYPES[words[1]]
                else:
                    raise fail(path, f"malformed PLY property line '{line}'")
                if name in el.names or name in el.lists:
                    raise fail(path, f"PLY element '{el.name}' declares property '{name}' twice")
                if code is None:
                    el.lists.append(name)
                else:
                    el.properties.append((name, code))
            else:
                raise fail(path, f"unexpected PLY header line '{line}'")
        offset = fh.tell()
    if fmt is None:
        raise fail(path, "PLY header has no 'format' line")
    return PlyHeader(fmt, elements, offset)


def read_ply_elements(path, header: PlyHeader, wanted) -> dict:
    """Read the named elements as structured arrays in native byte order.

    Elements before the last wanted one are skipped; their size must be
    computable, so they may not hold list properties. The byte (binary) or
    line (ASCII) count implied by the header is checked against the file
    before anything is allocated.
    """
    wanted = list(wanted)
    order = _FORMATS[header.format]
    last = max(i for i, el in enumerate(header.elements) if el.name in wanted)
    needed = header.elements[: last + 1]
    for el in needed:
        if el.lists and (el.name in wanted or order is not None):
            raise fail(path, f"PLY element '{el.name}' has list properties {el.lists}; "
                             f"Gaussian splat files have none")
    if order is None:
        return _read_ascii(path, header, needed, wanted)
    sizes = [el.count * el.dtype(order).itemsize for el in needed]
    available = file_size(path) - header.data_offset
    if sum(sizes) > available:
        counts = ", ".join(f"{el.count} x '{el.name}'" for el in needed)
        raise fail(path, f"file is truncated: the header promises {counts} "
                         f"({sum(sizes)} bytes of data) but only {available} bytes follow the header")
    if last == len(header.elements) - 1 and not any(el.lists for el in header.elements) \
            and available > sum(sizes):
        warn_trailing(path, available - sum(sizes), "the last PLY element")
    out = {}
    offset = header.data_offset
    native = "<" if np.little_endian else ">"
    with open(path, "rb") as fh:
        for el, size in zip(needed, sizes):
            if el.name in wanted:
                fh.seek(offset)
                arr = np.fromfile(fh, dtype=el.dtype(order), count=el.count)
                if arr.shape[0] != el.count:  # pragma: no cover - size checked above
                    raise fail(path, f"file is truncated inside element '{el.name}'")
                if order != native:
                    arr = arr.astype(el.dtype("="))
                out[el.name] = arr
            offset += size
    return out


_ASCII_BLOCK_BYTES = 1 << 20  # text read at a time: bounds the temporaries of a block


_ASCII_MAX_LINE = 1 << 22  # a row of a few hundred numbers is far shorter


class _AsciiLines:
    """Non-blank lines of an ASCII PLY body, read about 1 MiB at a time.

    :meth:`take` hands out at most about 1 MiB of text at once however long
    the lines are, and a line longer than ``_ASCII_MAX_LINE`` is an error, so
    the text held in memory stays bounded whatever the file holds.
    """

    def __init__(self, path, fh):
        self.path, self.fh = path, fh
        self.lines: list = []
        self.pos = 0
        self.buffered = 0  # bytes in self.lines[self.pos:]
        self.tail = b""
        self.eof = False

    def _fill(self):
        raw = self.fh.read(_ASCII_BLOCK_BYTES)
        if not raw:
            self.eof = True
            raw, self.tail = self.tail, b""
        elif b"\n" in raw:
            raw, self.tail = (self.tail + raw).rsplit(b"\n", 1)
        else:
            raw, self.tail = b"", self.tail + raw
        if len(self.tail) > _ASCII_MAX_LINE:
            raise fail(self.path, f"ASCII PLY body has a line longer than {_ASCII_MAX_LINE} bytes "
                                  f"(corrupt file or binary data under an ascii header)")
        new = [ln for ln in raw.split(b"\n") if ln.strip()]
        self.lines = self.lines[self.pos:] + new
        self.pos = 0
        self.buffered += sum(map(len, new))

    def take(self, k: int) -> list:
        """Up to ``k`` lines, fewer when they hold more than ~1 MiB; none only at the end."""
        # read on while short of k lines and of ~1 MiB of text; an empty buffer always
        # reads on (blank lines, or a line longer than one read)
        while not self.eof and (self.pos == len(self.lines) or (
                len(self.lines) - self.pos < k and self.buffered < _ASCII_BLOCK_BYTES)):
            self._fill()
        out = self.lines[self.pos:self.pos + k]
        self.pos += len(out)
        self.buffered -= sum(map(len, out))
        return out


def _read_ascii(path, header, needed, wanted) -> dict:
    """ASCII elements, parsed by numpy one block of lines at a time.

    A row of ``m`` values takes at least ``2 m`` bytes (``"0 0 ... 0\\n"``), so
    counts that the file cannot hold are refused before anything is
    allocated; memory is then the records themselves plus one block.
    """
    available = file_size(path) - header.data_offset
    least = sum(el.count * 2 * max(1, len(el.properties) + len(el.lists)) for el in needed) - 1
    if least > available:
        counts = ", ".join(f"{el.count} x '{el.name}'" for el in needed)
        raise fail(path, f"file is truncated: the header promises {counts} ASCII rows "
                         f"(at least {least} bytes) but only {available} bytes follow the header")
    out = {}
    with open(path, "rb") as fh:
        fh.seek(header.data_offset)
        lines = _AsciiLines(path, fh)
        for el in needed:
            if el.name in wanted:
                out[el.name] = _parse_ascii_element(path, el, lines)
                continue
            left = el.count
            while left:
                got = len(lines.take(min(left, 1 << 16)))
                if not got:
                    raise fail(path, f"file is truncated: element '{el.name}' needs {el.count} "
                                     f"lines but the file holds only {el.count - left}")
                left -= got
        if needed and needed[-1] is header.elements[-1] and lines.take(1):
            # as the binary reader does for bytes after the last element
            warn_caller(f"{os.fspath(path)}: ignoring the lines after the last PLY element (the header "
                        f"promises {needed[-1].count} '{needed[-1].name}' rows)")
    return out


def _ascii_row_error(path, el: PlyElement, text: str, first_row: int):
    """The FormatError for the first bad row of a block numpy could not parse (error path only)."""
    nprop = len(el.properties)
    for i, line in enumerate(text.split("\n")):
        words = line.split()
        if len(words) != nprop:
            return fail(path, f"ASCII element '{el.name}' row {first_row + i} has {len(words)} "
                              f"values; each row needs {nprop}")
        for word, (name, _) in zip(words, el.properties):
            try:
                float(word)
            except ValueError:
                return fail(path, f"ASCII element '{el.name}' row {first_row + i}: property "
                                  f"'{name}' is {word[:40]!r}, not a number")
    return fail(path, f"ASCII element '{el.name}' rows {first_row}-{first_row + i} could "
                      f"not be parsed as numbers")


def _parse_ascii_element(path, el: PlyElement, lines: _AsciiLines) -> np.ndarray:
    nprop = len(el.properties)
    if nprop == 0 and el.count:
        raise fail(path, f"ASCII element '{el.name}' has no properties")
    rec = np.empty(el.count, dtype=el.dtype("="))
    # ~1 MiB of text for values of ~20 characters; numpy's parser peaks at a few times that
    rows_per_block = max(1, _ASCII_BLOCK_BYTES // (20 * max(nprop, 1)))
    done = 0
    while done < el.count:
        block = lines.take(min(rows_per_block, el.count - done))
        if not block:
            raise fail(path, f"file is truncated: element '{el.name}' needs {el.count} lines "
                             f"but the file holds only {done}")
        try:
            text = b"\n".join(block).decode("ascii")
        except UnicodeDecodeError:
            raise fail(path, "ASCII PLY body contains non-ASCII bytes") from None
        del block
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "input contained no data" is checked below
                vals = np.loadtxt(text.split("\n"), dtype=np.float64, comments=None, ndmin=2)
        except ValueError:
            raise _ascii_row_error(path, el, text, done) from None
        del text
        if vals.shape[1] != nprop:
            raise fail(path, f"ASCII element '{el.name}' should have {nprop} values on each of its "
                             f"{el.count} lines; row {done} has {vals.shape[1]}")
        m = vals.shape[0]
        for j, (name, code) in enumerate(el.properties):
            col = vals[:, j]
            if code[0] in "iu":
                info = np.iinfo(np.dtype(code))
                ok = np.isfinite(col) & (col == np.round(col)) & (col >= info.min) & (col <= info.max)
                if not ok.all():
                    raise fail(path, f"ASCII property '{name}' holds a value that is not a {code} "
                                     f"integer (row {done + int(np.argmin(ok))})")
            with np.errstate(over="ignore"):
                rec[name][done:done + m] = col
        done += m
    return rec


def columns(struct: np.ndarray, names) -> np.ndarray:
    """The named fields of a structured array as an (n, len(names)) float32 array.

    Files whose fields are all native float32 (nearly every 3DGS PLY) take a
    fast path through a 2-D view of the records instead of per-field copies.
    """
    fields = struct.dtype.names
    names = list(names)
    n = struct.shape[0]
    if not names:
        return np.empty((n, 0), np.float32)
    f32 = np.dtype(np.float32)
    if struct.flags.c_contiguous and struct.dtype.itemsize == 4 * len(fields) \
            and all(struct.dtype.fields[f][0] == f32 for f in fields):
        flat = struct.view(np.float32).reshape(n, len(fields))
        # np.take returns C-contiguous rows (fancy indexing would give F order here)
        return np.take(flat, [fields.index(name) for name in names], axis=1)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.stack([struct[name].astype(np.float32) for name in names], axis=1)


_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
_NORMALS = ["nx", "ny", "nz"]
_REST_RE = re.compile(r"^f_rest_(\d+)$")


def _rounded(values) -> bool:
    """Whether a finite float32 rounding of ``values`` (wider numbers) changes one (overflow is non-finite)."""
    with np.errstate(over="ignore"):
        f32 = values.astype(np.float32)
    return bool(np.any((f32 != values) & np.isfinite(f32)))


def read_standard_ply(path, header: PlyHeader, drop_nonfinite: bool = False) -> GaussianScene:
    """Decode a standard 3DGS PLY file (see the module docstring)."""
    vertex = header.element("vertex")
    if vertex is None:
        raise fail(path, "PLY file has no 'vertex' element, so it holds no Gaussians")
    names = vertex.names
    missing = [p for p in _REQUIRED if p not in names]
    if missing:
        raise fail(path, f"PLY 'vertex' element lacks the 3DGS properties {missing} "
                         f"(is this a point cloud rather than a Gaussian splat file?)")
    rest_found = [m for m in map(_REST_RE.match, names) if m]
    rest_idx = sorted(int(m.group(1)) for m in rest_found)  # repeats kept (f_rest_1 and f_rest_01): refused below
    rest_names = {int(m.group(1)): m.group(0) for m in rest_found}
    if rest_idx != list(range(len(rest_idx))) or len(rest_idx) not in (0, 9, 24, 45):
        raise fail(path, f"PLY file has {len(rest_idx)} f_rest_* properties "
                         f"(indices {rest_idx[:3]}...); a 3DGS file has 0, 9, 24 or 45 "
                         f"numbered from 0 (SH degree 0-3)")
    vert = read_ply_elements(path, header, ["vertex"])["vertex"]
    n = vertex.count
    k = 1 + len(rest_idx) // 3
    rest = [rest_names[i] for i in range(len(rest_idx))]  # as named in the file (f_rest_00 is f_rest_0)
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = columns(vert, ["f_dc_0", "f_dc_1", "f_dc_2"])
    if rest:
        # f_rest is channel-major: column c*(k-1) + j is coefficient j+1 of channel c.
        sh[:, 1:, :] = columns(vert, rest).reshape(n, 3, k - 1).transpose(0, 2, 1)
    # binary files only: an ASCII file declaring doubles may print float32 data at its shortest
    narrowed = [name for name in _REQUIRED + rest if header.format != "ascii"
                and vert.dtype[name] != np.float32 and _rounded(vert[name])]
    if narrowed:
        warn_caller(f"{os.fspath(path)}: {', '.join(narrowed[:4])}{' ...' if len(narrowed) > 4 else ''} "
                    f"{'holds' if len(narrowed) == 1 else 'hold'} values beyond float32; 3DGS scenes are "
                    f"float32, so they are read rounded to it (a relative change of up to 6e-8)")
    extra = {}
    # all-zero normals carry nothing (dropped); a -0.0 counts as stored, so a copy keeps every bit
    zero_normals = not any(np.any(vert[name]) or np.any(np.signbit(vert[name]))
                           for name in _NORMALS if name in names)
    for name in names:
        if name in _REQUIRED or name in rest:
            continue
        if name in _NORMALS and zero_normals:
            continue
        extra[name] = np.ascontiguousarray(vert[name])
    # One gathered copy per array straight from the records keeps the peak memory low.
    return finish_scene(path, columns(vert, ["x", "y", "z"]),
                        columns(vert, ["rot_0", "rot_1", "rot_2", "rot_3"]),
                        columns(vert, ["scale_0", "scale_1", "scale_2"]),
                        columns(vert, ["opacity"])[:, 0].copy(), sh, extra, drop_nonfinite,
                        fields=ply_field_names(k), layout=tuple(vertex.properties))


def ply_field_names(k: int) -> dict:
    """PLY property names of each column of the scene arrays, for error messages."""
    sh = [f"f_dc_{c}" if j == 0 else f"f_rest_{c * (k - 1) + j - 1}"
          for j in range(k) for c in range(3)]  # sh[:, j, c] flattened row-major
    return {"means": ["x", "y", "z"], "quats": [f"rot_{i}" for i in range(4)],
            "log_scales": [f"scale_{i}" for i in range(3)], "opacity_logits": ["opacity"],
            "sh": sh}


def standard_property_names(sh_degree: int) -> list:
    """Property names in the trainer's order for an SH degree (normals included)."""
    k = (sh_degree + 1) ** 2
    return (["x", "y", "z"] + _NORMALS + ["f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(3 * (k - 1))]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def _column(scene: GaussianScene, name: str) -> np.ndarray:
    """The values of one PLY property of ``scene`` (zeros for normals it does not hold)."""
    if name in scene.extra:
        return scene.extra[name]
    if name in _NORMALS:
        return np.zeros(len(scene), np.float32)
    k = scene.sh.shape[1]
    rest = _REST_RE.match(name)
    if rest:  # channel-major: f_rest_{c (K-1) + j} is coefficient j + 1 of channel c
        c, j = divmod(int(rest.group(1)), k - 1)
        return scene.sh[:, 1 + j, c]
    if name.startswith("f_dc_"):
        return scene.sh[:, 0, int(name[5:])]
    if name == "opacity":
        return scene.opacity_logits
    for prefix, arr in (("scale_", scene.log_scales), ("rot_", scene.quats)):
        if name.startswith(prefix):
            return arr[:, int(name[len(prefix):])]
    return scene.means[:, "xyz".index(name)]


def _own_code(name: str, arr: np.ndarray) -> str:
    """The PLY type code of an array's own dtype (bool as uchar); int64 and uint64 are refused."""
    code = arr.dtype.str[1:] if arr.dtype.kind != "b" else "u1"
    if code not in _NAMES:
        raise ValidationError(f"extra property '{name}' has dtype {arr.dtype}, which PLY cannot "
                              f"store; cast it to int32 or float32 first")
    return code


def _holds(values: np.ndarray, code: str) -> bool:
    """Whether every value survives a cast to the type ``code`` and back unchanged (sign of zero included)."""
    if values.dtype.kind == "b":
        return code == "u1"
    with np.errstate(over="ignore", invalid="ignore"):
        back = values.astype(code).astype(values.dtype)
    if values.dtype.kind == "f":
        return bool(np.array_equal(back, values, equal_nan=True)
                    and np.array_equal(np.signbit(back), np.signbit(values)))
    return bool(np.array_equal(back, values))


def _layout_names(scene: GaussianScene) -> list | None:
    """The property names of ``scene.layout`` when it still fits the scene's arrays, else ``None``.

    It fits when it names every standard property of the scene's SH degree
    (and no other ``f_rest``), every ``extra`` entry and nothing else (normals
    that the scene does not hold are written as zeros).
    """
    layout = scene.layout
    if not layout:
        return None
    names = [name for name, _ in layout]
    rest = sorted(int(m.group(1)) for m in map(_REST_RE.match, names) if m)
    standard = set(_REQUIRED) | set(_NORMALS)
    own = {name for name in names if name not in standard and not _REST_RE.match(name)}
    fits = (len(set(names)) == len(names)
            and all(name in names for name in _REQUIRED)
            and rest == list(range(3 * (scene.sh.shape[1] - 1)))
            and all(f"f_rest_{i}" in names for i in rest)
            and own == set(scene.extra) - set(_NORMALS)
            and all(name in names for name in _NORMALS if name in scene.extra)
            and all(code in _NAMES for _, code in layout))
    return names if fits else None


def write_standard_ply(path, scene: GaussianScene) -> None:
    """Write ``scene`` as a binary little-endian 3DGS PLY file, atomically.

    A scene read from a PLY file is written with that file's properties, in
    its order and with its types (:attr:`GaussianScene.layout`), as long as
    the layout still fits the scene: same SH degree, same ``extra`` names.
    Normals the file held as zeros are written as zeros again. A property
    whose values its recorded type cannot hold exactly is written in the
    values' own type instead (float32 for the standard properties).

    Otherwise properties follow the trainer's order (see
    :func:`standard_property_names`) as float32 (normals too, unless their
    values need a wider type), then the remaining ``scene.extra`` entries
    with their own dtypes.

    In both cases bool is stored as uchar; int64 and uint64 extras are
    rejected because PLY cannot hold them losslessly: cast them first.
    """
    n = len(scene)
    for name in scene.extra:
        if name in _REQUIRED or _REST_RE.match(name) or not _NAME_RE.match(name):
            raise ValidationError(f"extra property '{name}' cannot be written to PLY: the name "
                                  f"is a standard 3DGS property or contains whitespace")
    names = _layout_names(scene)
    if names is None:
        recorded = dict.fromkeys(_NORMALS, "f4")  # the trainer's normals are float32
        names = standard_property_names(scene.sh_degree)
        names += [name for name in scene.extra if name not in _NORMALS]
    else:
        recorded = dict(scene.layout)
    fields, values = [], []
    for name in names:
        col = _column(scene, name)
        code = recorded.get(name)
        if code is None or not _holds(col, code):
            code = _own_code(name, col)
        fields.append((name, "<" + code))
        values.append(col)
    rec = np.empty(n, dtype=np.dtype(fields))
    for (name, _), col in zip(fields, values):
        rec[name] = col
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    lines += [f"property {_NAMES[t[1:]]} {name}" for name, t in fields]
    lines.append("end_header")
    head = ("\n".join(lines) + "\n").encode("ascii")
    atomic_write(path, [head, rec.tobytes()])
