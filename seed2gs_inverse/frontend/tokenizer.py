"""Text tokenizers: the model's own ``tokenizer.json`` run by HuggingFace ``tokenizers``.

The ids a text encoder sees must be exactly those of the tokenizer it was
trained with, so nothing is re-implemented here: the file's normaliser,
pre-tokeniser and model (WordPiece or byte-level BPE) run in the
``tokenizers`` library, the same code the ``transformers`` processors use.
This module only adds the conventions of the exported graphs on top:

- :class:`BertTokenizer` (GroundingDINO, ``bert-base-uncased``): ids are
  ``[CLS] tokens [SEP]``, truncated to a maximum length with ``[SEP]``
  kept last (``BertTokenizerFast`` with ``truncation=True``). A plain
  ``vocab.txt`` is read as ``BertWordPieceTokenizer`` (lower-casing,
  accent stripping, punctuation split, ``##`` WordPiece).
- :class:`ClipTokenizer` (OWL-ViT, SAM3): ``<|startoftext|> tokens
  <|endoftext|>`` truncated to the context length with the end token kept
  last, then padded with the model's pad id (``tokenizer_config.json`` /
  ``special_tokens_map.json`` next to the file when present, else the
  file's own padding id, else 0 as OpenAI CLIP and samexporter's SAM3
  runtime). The attention mask is 1 on start..end.

:func:`load_tokenizer` picks the class from the model type in the file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._extras import missing_extra
from ..errors import FormatError, ValidationError
from ..io._common import check_regular

__all__ = ["BertTokenizer", "ClipTokenizer", "load_tokenizer"]


#: Largest tokenizer file read (bytes). Public tokenizer.json files are a few
#: megabytes (BERT's and CLIP's under 4 MB, multilingual ones under 20 MB);
#: the cap keeps a device or a huge file from being read into memory.
MAX_TOKENIZER_BYTES = 64 << 20


def _check_file(path: Path) -> None:
    """FormatError naming ``path`` when it exists but is not a regular file of at most MAX_TOKENIZER_BYTES."""
    check_regular(path, "tokenizer file")  # a FIFO would block the read for ever, /dev/zero never end
    if path.is_file() and path.stat().st_size > MAX_TOKENIZER_BYTES:
        raise FormatError(f"{path}: {path.stat().st_size} bytes, more than the {MAX_TOKENIZER_BYTES} a tokenizer "
                          f"file may have; check the path in the models configuration")


def _read_json(path: Path) -> dict:
    """The JSON object of a tokenizer.json (with a ``model`` object), or a FormatError naming the file."""
    _check_file(path)
    try:
        with open(path, "r", encoding="utf-8") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise FormatError(f"{path}: tokenizer file not found (check the models configuration)") from None
    except OSError as exc:
        raise FormatError(f"{path}: cannot read the tokenizer file ({exc.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"{path}: not a valid tokenizer.json ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("model"), dict):
        raise FormatError(f"{path}: not a HuggingFace tokenizer.json (no 'model' object)")
    return data


def _library():
    """The ``tokenizers`` module, imported on first use (large to load; only text prompts need it)."""
    try:
        import tokenizers
    except ImportError as exc:
        raise missing_extra("models", "reading a tokenizer.json (text prompts)", exc) from None
    return tokenizers


def _load(path: Path, kind: str):
    """``tokenizers.Tokenizer`` of a tokenizer.json whose model type is ``kind``."""
    data = _read_json(path)
    found = data["model"].get("type")
    if found != kind:
        what = "WordPiece (BERT)" if kind == "WordPiece" else "BPE (CLIP)"
        raise FormatError(f"{path}: expected a {what} tokenizer.json, found model type {found!r}")
    tk = _library()
    try:
        return tk.Tokenizer.from_str(json.dumps(data))
    except Exception as exc:  # the library raises its own Exception subclass
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FormatError(f"{path}: the tokenizers library cannot read this tokenizer.json "
                          f"({first}); save it again with transformers' save_pretrained") from None


def _special_token(path: Path, key: str):
    """``key`` (e.g. ``pad_token``) from the files saved next to a tokenizer.json."""
    for name in ("special_tokens_map.json", "tokenizer_config.json"):
        f = path.parent / name
        if not f.is_file():
            continue
        _check_file(f)
        try:
            value = json.loads(f.read_text(encoding="utf-8")).get(key)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
            raise FormatError(f"{f}: not a valid JSON object (it sits next to the tokenizer "
                              f"{path.name}; fix or remove it)") from None
        if isinstance(value, dict):
            value = value.get("content")
        if isinstance(value, str):
            return value
    return None


class _Base:
    """Shared id/token look-ups over a ``tokenizers.Tokenizer``."""

    def __init__(self, tokenizer, name: str):
        self.tokenizer = tokenizer
        self.name = name

    def _require(self, token: str, what: str) -> int:
        """Id of ``token``, or a FormatError saying the vocabulary is not a ``what`` one."""
        tid = self.tokenizer.token_to_id(token)
        if tid is None:
            raise FormatError(f"{self.name}: the vocabulary has no {token} token; is this a {what} tokenizer?")
        return int(tid)

    def tokenize(self, text: str) -> list[str]:
        """The model's tokens of ``text`` (no special tokens)."""
        return list(self.tokenizer.encode(str(text), add_special_tokens=False).tokens)

    def _ids(self, text: str) -> list[int]:
        """The model's ids of ``text`` (no special tokens)."""
        return list(self.tokenizer.encode(str(text), add_special_tokens=False).ids)

    def token_id(self, token: str) -> int | None:
        """Id of ``token``, or None when it is not in the vocabulary."""
        tid = self.tokenizer.token_to_id(token)
        return None if tid is None else int(tid)

    def convert_ids_to_tokens(self, ids) -> list[str]:
        """Tokens of ``ids`` (any shape, flattened); unknown ids give the unknown token."""
        out = []
        for i in np.asarray(ids).reshape(-1):
            tok = self.tokenizer.id_to_token(int(i))
            out.append(self.unk_token if tok is None else tok)
        return out

    @property
    def vocab_size(self) -> int:
        """Number of ids, added tokens included."""
        return int(self.tokenizer.get_vocab_size(with_added_tokens=True))


class BertTokenizer(_Base):
    """BERT WordPiece tokenizer (``bert-base-uncased`` for GroundingDINO).

    Parameters
    ----------
    tokenizer : tokenizers.Tokenizer
        With a WordPiece model; use :meth:`from_file`.
    name : str
        Used in messages (the file).
    unk_token, cls_token, sep_token : str
    """

    def __init__(self, tokenizer, name: str = "tokenizer", unk_token: str = "[UNK]",
                 cls_token: str = "[CLS]", sep_token: str = "[SEP]"):
        super().__init__(tokenizer, name)
        self.unk_token = unk_token
        self._require(unk_token, "BERT")
        self.cls_id = self._require(cls_token, "BERT")
        self.sep_id = self._require(sep_token, "BERT")

    @classmethod
    def from_file(cls, path) -> "BertTokenizer":
        """Read a ``tokenizer.json`` (WordPiece model) or a plain ``vocab.txt``."""
        path = Path(path)
        if path.suffix == ".txt":
            _check_file(path)
            if not path.is_file():
                raise FormatError(f"{path}: vocabulary file not found")
            tk = _library()
            try:
                impl = tk.implementations.BertWordPieceTokenizer(str(path), lowercase=True)
            except Exception as exc:
                raise FormatError(f"{path}: not a BERT vocab.txt ({exc})") from None
            return cls(impl._tokenizer, name=str(path))
        tok = _load(path, "WordPiece")
        unk = _read_json(path)["model"].get("unk_token") or "[UNK]"
        return cls(tok, name=str(path), unk_token=unk)

    def encode(self, text: str, max_length: int | None = None) -> list[int]:
        """``[CLS] tokens [SEP]`` ids, truncated to ``max_length`` (keeping [SEP])."""
        ids = self._ids(text)
        if max_length is not None and len(ids) + 2 > max_length:
            ids = ids[:max(0, max_length - 2)]
        return [self.cls_id] + ids + [self.sep_id]


class ClipTokenizer(_Base):
    """CLIP byte-level BPE tokenizer (OWL-ViT, SAM3's language encoder).

    Parameters
    ----------
    tokenizer : tokenizers.Tokenizer
        With a BPE model; use :meth:`from_file`.
    pad_id : int
        Id that fills the sequence after ``<|endoftext|>``.
    name : str
    """

    def __init__(self, tokenizer, pad_id: int = 0, name: str = "tokenizer",
                 bos_token: str = "<|startoftext|>", eos_token: str = "<|endoftext|>"):
        super().__init__(tokenizer, name)
        self.unk_token = eos_token
        self.bos_id = self._require(bos_token, "CLIP")
        self.eos_id = self._require(eos_token, "CLIP")
        self.pad_id = int(pad_id)

    @classmethod
    def from_file(cls, path, pad_id: int | None = None) -> "ClipTokenizer":
        """Read a CLIP ``tokenizer.json``; the pad id as described in the module docstring."""
        path = Path(path)
        tok = _load(path, "BPE")
        if pad_id is None:
            pad = _special_token(path, "pad_token")
            if pad is not None:
                pad_id = tok.token_to_id(pad)
                if pad_id is None:
                    raise FormatError(f"{path}: the pad token {pad!r} named next to it is not in "
                                      "its vocabulary")
            else:
                padding = _read_json(path).get("padding") or {}
                pad_id = padding.get("pad_id") if isinstance(padding.get("pad_id"), int) else 0
        return cls(tok, pad_id=int(pad_id), name=str(path))

    def encode(self, text: str, context_length: int | None = None):
        """``(ids, attention_mask)`` int64 arrays: BOS, tokens, EOS, then padding.

        With ``context_length`` the ids are truncated (EOS kept last) and
        padded with ``pad_id``; the mask is 1 on BOS..EOS.
        """
        ids = [self.bos_id] + self._ids(text) + [self.eos_id]
        if context_length is not None:
            if context_length < 2:
                raise ValidationError("context_length: need room for the start and end tokens")
            if len(ids) > context_length:
                ids = ids[:context_length - 1] + [self.eos_id]
            n = len(ids)
            ids = ids + [self.pad_id] * (context_length - n)
        else:
            n = len(ids)
        mask = np.zeros(len(ids), np.int64)
        mask[:n] = 1
        return np.asarray(ids, np.int64), mask


def load_tokenizer(path):
    """BertTokenizer or ClipTokenizer, by the model type in the file (``vocab.txt`` = BERT)."""
    path = Path(path)
    if path.suffix == ".txt":
        return BertTokenizer.from_file(path)
    kind = _read_json(path)["model"].get("type")
    if kind == "WordPiece":
        return BertTokenizer.from_file(path)
    if kind == "BPE":
        return ClipTokenizer.from_file(path)
    raise FormatError(f"{path}: unsupported tokenizer model type {kind!r} (expected WordPiece or BPE)")
