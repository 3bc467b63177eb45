"""Text tokenizers read from a HuggingFace ``tokenizer.json`` (no extra dependency).

- :class:`BertTokenizer`: BERT basic tokenization (clean text, CJK spacing,
  lower-casing, accent stripping, punctuation split) + greedy longest-match
  WordPiece, as ``bert-base-uncased`` uses for GroundingDINO. Reads the
  ``WordPiece`` model of a ``tokenizer.json`` or a plain ``vocab.txt``.
- :class:`ClipTokenizer`: CLIP's byte-level BPE with the ``</w>`` end-of-word
  suffix (OpenAI ``simple_tokenizer`` semantics), for OWL-ViT and SAM3's
  language encoder. Reads the ``BPE`` model (vocab + merges) of a
  ``tokenizer.json``.

:func:`load_tokenizer` picks the class from the file.
"""

from __future__ import annotations

import json
import re
import unicodedata
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..errors import FormatError, ValidationError

__all__ = ["BertTokenizer", "ClipTokenizer", "load_tokenizer"]


def _read_json(path: Path) -> dict:
    try:
        with open(path, "r", encoding="utf-8") as fh:
            data = json.load(fh)
    except FileNotFoundError:
        raise FormatError(f"{path}: tokenizer file not found (check the models configuration)") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"{path}: not a valid tokenizer.json ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("model"), dict):
        raise FormatError(f"{path}: not a HuggingFace tokenizer.json (no 'model' object)")
    return data


# ------------------------------------------------------------------ BERT
def _is_punct(ch: str) -> bool:
    cp = ord(ch)
    if 33 <= cp <= 47 or 58 <= cp <= 64 or 91 <= cp <= 96 or 123 <= cp <= 126:
        return True
    return unicodedata.category(ch).startswith("P")


def _is_cjk(cp: int) -> bool:
    return (0x4E00 <= cp <= 0x9FFF or 0x3400 <= cp <= 0x4DBF or 0x20000 <= cp <= 0x2A6DF
            or 0x2A700 <= cp <= 0x2B73F or 0x2B740 <= cp <= 0x2B81F or 0x2B820 <= cp <= 0x2CEAF
            or 0xF900 <= cp <= 0xFAFF or 0x2F800 <= cp <= 0x2FA1F)


class BertTokenizer:
    """BERT uncased WordPiece tokenizer.

    Parameters
    ----------
    vocab : dict str -> int
    lowercase : bool
        Lower-case and strip accents (``bert-base-uncased``).
    unk_token, cls_token, sep_token : str
    prefix : str
        WordPiece continuation prefix (``"##"``).
    max_chars : int
        Longer words become ``[UNK]`` (BERT's ``max_input_chars_per_word``).
    """

    def __init__(self, vocab: dict, lowercase: bool = True, unk_token: str = "[UNK]",
                 cls_token: str = "[CLS]", sep_token: str = "[SEP]", prefix: str = "##",
                 max_chars: int = 100, name: str = "tokenizer"):
        self.vocab = dict(vocab)
        self.inv = {i: t for t, i in self.vocab.items()}
        self.lowercase = lowercase
        self.unk_token, self.prefix, self.max_chars = unk_token, prefix, max_chars
        for tok in (unk_token, cls_token, sep_token):
            if tok not in self.vocab:
                raise FormatError(f"{name}: the vocabulary has no {tok} token; is this a BERT tokenizer?")
        self.cls_id, self.sep_id = self.vocab[cls_token], self.vocab[sep_token]

    @classmethod
    def from_file(cls, path) -> "BertTokenizer":
        """Read a ``tokenizer.json`` (WordPiece model) or a ``vocab.txt``."""
        path = Path(path)
        if path.suffix == ".txt":
            try:
                lines = path.read_text(encoding="utf-8").splitlines()
            except FileNotFoundError:
                raise FormatError(f"{path}: vocabulary file not found") from None
            return cls({t: i for i, t in enumerate(lines)}, name=str(path))
        data = _read_json(path)
        model = data["model"]
        if model.get("type") != "WordPiece" or not isinstance(model.get("vocab"), dict):
            raise FormatError(f"{path}: expected a WordPiece (BERT) tokenizer.json, found model "
                              f"type {model.get('type')!r}")
        norm = data.get("normalizer") or {}
        lower = bool(norm.get("lowercase", True))
        return cls(model["vocab"], lowercase=lower, unk_token=model.get("unk_token", "[UNK]"),
                   prefix=model.get("continuing_subword_prefix", "##"),
                   max_chars=int(model.get("max_input_chars_per_word", 100)), name=str(path))

    def basic_tokenize(self, text: str) -> list[str]:
        """Clean, space CJK characters, lower-case/strip accents, split punctuation."""
        out = []
        for ch in text:
            cp = ord(ch)
            if cp == 0 or cp == 0xFFFD or (unicodedata.category(ch) in ("Cc", "Cf") and ch not in "\t\n\r"):
                continue
            if _is_cjk(cp):
                out.append(f" {ch} ")
            elif ch.isspace():
                out.append(" ")
            else:
                out.append(ch)
        words = []
        for word in "".join(out).split():
            if self.lowercase:
                word = "".join(c for c in unicodedata.normalize("NFD", word.lower())
                               if unicodedata.category(c) != "Mn")
            cur = ""
            for ch in word:
                if _is_punct(ch):
                    if cur:
                        words.append(cur)
                    words.append(ch)
                    cur = ""
                else:
                    cur += ch
            if cur:
                words.append(cur)
        return words

    def wordpiece(self, word: str) -> list[str]:
        """Greedy longest-match-first split of one word; ``[UNK]`` if impossible."""
        if len(word) > self.max_chars:
            return [self.unk_token]
        pieces, start = [], 0
        while start < len(word):
            end = len(word)
            while end > start:
                sub = word[start:end] if start == 0 else self.prefix + word[start:end]
                if sub in self.vocab:
                    pieces.append(sub)
                    break
                end -= 1
            else:
                return [self.unk_token]
            start = end
        return pieces

    def tokenize(self, text: str) -> list[str]:
        return [p for w in self.basic_tokenize(text) for p in self.wordpiece(w)]

    def encode(self, text: str, max_length: int | None = None) -> list[int]:
        """``[CLS] tokens [SEP]`` ids, truncated to ``max_length`` (keeping [SEP])."""
        ids = [self.vocab[t] for t in self.tokenize(text)]
        if max_length is not None and len(ids) + 2 > max_length:
            ids = ids[:max(0, max_length - 2)]
        return [self.cls_id] + ids + [self.sep_id]

    def token_id(self, token: str) -> int | None:
        return self.vocab.get(token)

    def convert_ids_to_tokens(self, ids) -> list[str]:
        return [self.inv.get(int(i), self.unk_token) for i in ids]


# ------------------------------------------------------------------ CLIP BPE
@lru_cache(maxsize=1)
def _bytes_to_unicode() -> dict:
    """GPT-2/CLIP reversible byte -> printable unicode character map."""
    bs = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1)) + list(range(ord("®"), ord("ÿ") + 1))
    cs = bs[:]
    n = 0
    for b in range(256):
        if b not in bs:
            bs.append(b)
            cs.append(256 + n)
            n += 1
    return dict(zip(bs, map(chr, cs)))


# CLIP's pre-tokenizer pattern; \p{L} / \p{N} written with the re module's classes.
_CLIP_PAT = re.compile(r"<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[^\W\d_]+|\d|(?:[^\s\w]|_)+",
                       re.IGNORECASE)


class ClipTokenizer:
    """CLIP byte-level BPE tokenizer.

    Parameters
    ----------
    vocab : dict str -> int
    merges : list of (str, str)
        BPE merges in priority order.
    bos_token, eos_token : str
        ``<|startoftext|>``, ``<|endoftext|>``.
    pad_id : int
        Id that fills the sequence after ``<|endoftext|>`` (0 in OpenAI CLIP,
        which is also the id of ``"!"`` that OWL-ViT's processor pads with).
    """

    def __init__(self, vocab: dict, merges, bos_token="<|startoftext|>", eos_token="<|endoftext|>",
                 suffix="</w>", pad_id: int = 0, name: str = "tokenizer"):
        self.vocab = dict(vocab)
        self.ranks = {tuple(m): i for i, m in enumerate(merges)}
        self.suffix = suffix
        for tok in (bos_token, eos_token):
            if tok not in self.vocab:
                raise FormatError(f"{name}: the vocabulary has no {tok} token; is this a CLIP tokenizer?")
        self.bos_id, self.eos_id, self.pad_id = self.vocab[bos_token], self.vocab[eos_token], int(pad_id)
        self._cache: dict[str, list[str]] = {}

    @classmethod
    def from_file(cls, path, pad_id: int | None = None) -> "ClipTokenizer":
        """Read the BPE model of a CLIP ``tokenizer.json``; added tokens join the vocabulary."""
        path = Path(path)
        data = _read_json(path)
        model = data["model"]
        if model.get("type") != "BPE" or not isinstance(model.get("vocab"), dict):
            raise FormatError(f"{path}: expected a BPE (CLIP) tokenizer.json, found model type "
                              f"{model.get('type')!r}")
        merges = []
        for m in model.get("merges", []):
            pair = m.split(" ") if isinstance(m, str) else list(m)
            if len(pair) != 2:
                raise FormatError(f"{path}: malformed BPE merge {m!r}")
            merges.append(tuple(pair))
        vocab = dict(model["vocab"])
        for tok in data.get("added_tokens", []) or []:
            if isinstance(tok, dict) and "content" in tok and "id" in tok:
                vocab.setdefault(tok["content"], int(tok["id"]))
        if pad_id is None:
            pad = (data.get("padding") or {}).get("pad_id")
            pad_id = int(pad) if isinstance(pad, int) else 0
        return cls(vocab, merges, suffix=model.get("end_of_word_suffix") or "</w>", pad_id=pad_id,
                   name=str(path))

    def bpe(self, token: str) -> list[str]:
        """Merge the byte-level characters of one word by merge priority."""
        if token in self._cache:
            return self._cache[token]
        word = list(token[:-1]) + [token[-1] + self.suffix]
        while len(word) > 1:
            pairs = [(self.ranks.get((a, b), None), i) for i, (a, b) in enumerate(zip(word[:-1], word[1:]))]
            pairs = [p for p in pairs if p[0] is not None]
            if not pairs:
                break
            _, at = min(pairs)
            first, second = word[at], word[at + 1]
            merged, i = [], 0
            while i < len(word):
                if i < len(word) - 1 and word[i] == first and word[i + 1] == second:
                    merged.append(first + second)
                    i += 2
                else:
                    merged.append(word[i])
                    i += 1
            word = merged
        self._cache[token] = word
        return word

    def tokenize(self, text: str) -> list[str]:
        text = " ".join(unicodedata.normalize("NFC", text).split()).lower()
        b2u = _bytes_to_unicode()
        out = []
        for tok in _CLIP_PAT.findall(text):
            if tok in ("<|startoftext|>", "<|endoftext|>"):
                out.append(tok)
                continue
            out.extend(self.bpe("".join(b2u[b] for b in tok.encode("utf-8"))))
        return out

    def encode(self, text: str, context_length: int | None = None):
        """``(ids, attention_mask)`` int64 arrays: BOS, tokens, EOS, then padding.

        With ``context_length`` the ids are truncated (EOS kept last) and
        padded with ``pad_id``; the mask is 1 on BOS..EOS.
        """
        unk = self.vocab.get("<|endoftext|>")
        ids = [self.bos_id] + [self.vocab.get(t, unk) for t in self.tokenize(text)] + [self.eos_id]
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
