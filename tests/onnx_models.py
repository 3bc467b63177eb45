"""Tiny ONNX models with the signatures of the supported exports, built in the test run.

Nothing here comes from a real export: every graph is a few deterministic
ops (average pools, a box-distance mask, token lookups) whose outputs the
tests can predict by hand, with the same input/output names, ranks and
dtypes as the real files (dynamic axes where the real ones have them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

F32, I64, I32, BOOL, U8 = (TensorProto.FLOAT, TensorProto.INT64, TensorProto.INT32,
                           TensorProto.BOOL, TensorProto.UINT8)

# SAM2 tiny geometry: encoder input S, low-res masks S/4.
S = 64
LOW = S // 4
IOU = np.array([[0.5, 0.9, 0.7]], np.float32)   # multimask scores: mask 1 (eroded) wins
ERODE = 4.0                                      # mask 1 = box eroded by 4 encoder pixels


def vi(name, dtype, shape):
    return helper.make_tensor_value_info(name, dtype, shape)


def const(name, array):
    return numpy_helper.from_array(np.asarray(array), name)


def save(path, nodes, inputs, outputs, inits=(), opset=17) -> Path:
    graph = helper.make_graph(list(nodes), Path(path).stem, list(inputs), list(outputs), list(inits))
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return Path(path)


def pool(src, dst, k):
    return helper.make_node("AveragePool", [src], [dst], kernel_shape=[k, k], strides=[k, k])


def _grid(n, step):
    """Pixel-centre coordinates of an n x n low-res grid in encoder pixels."""
    c = (np.arange(n, dtype=np.float32) + 0.5) * step
    return np.broadcast_to(c[None, :], (n, n))[None, None].copy(), np.broadcast_to(c[:, None], (n, n))[None, None].copy()


def box_distance_nodes(coords, prefix=""):
    """Nodes computing d = min(X - x0, x1 - X, Y - y0, y1 - Y) on the LOW grid.

    Box corners are points 0 and 1 of ``coords`` (L, P, 2); output ``{prefix}d``
    has shape (L, 1, LOW, LOW).
    """
    p = prefix
    xg, yg = _grid(LOW, S / LOW)
    inits = [const(p + "xg", xg), const(p + "yg", yg), const(p + "i0", np.array(0, np.int64)),
             const(p + "i1", np.array(1, np.int64)), const(p + "shp", np.array([-1, 1, 1, 1], np.int64))]
    nodes = [
        helper.make_node("Gather", [coords, p + "i0"], [p + "p0"], axis=1),
        helper.make_node("Gather", [coords, p + "i1"], [p + "p1"], axis=1),
    ]
    for corner, pt in (("0", "p0"), ("1", "p1")):
        for ax, axis_idx in (("x", "i0"), ("y", "i1")):
            nodes.append(helper.make_node("Gather", [p + pt, p + axis_idx], [p + ax + corner + "f"], axis=1))
            nodes.append(helper.make_node("Reshape", [p + ax + corner + "f", p + "shp"], [p + ax + corner]))
    nodes += [
        helper.make_node("Sub", [p + "xg", p + "x0"], [p + "dx0"]),
        helper.make_node("Sub", [p + "x1", p + "xg"], [p + "dx1"]),
        helper.make_node("Sub", [p + "yg", p + "y0"], [p + "dy0"]),
        helper.make_node("Sub", [p + "y1", p + "yg"], [p + "dy1"]),
        helper.make_node("Min", [p + "dx0", p + "dx1", p + "dy0", p + "dy1"], [p + "d"]),
    ]
    return nodes, inits


def sam2_encoder(path, layout="samexporter", size=S):
    names = (["high_res_feats_0", "high_res_feats_1", "image_embed"] if layout == "samexporter"
             else ["image_features_0", "image_features_1", "image_embeddings"])
    nodes = [pool("image", names[0], 4), pool("image", names[1], 8), pool("image", names[2], 16)]
    return save(path, nodes, [vi("image", F32, [1, 3, size, size])],
                [vi(names[0], F32, [1, 3, size // 4, size // 4]), vi(names[1], F32, [1, 3, size // 8, size // 8]),
                 vi(names[2], F32, [1, 3, size // 16, size // 16])])


def _multimask_nodes(d):
    inits = [const("erode", np.array(ERODE, np.float32))]
    nodes = [helper.make_node("Sub", [d, "erode"], ["d_er"]),
             helper.make_node("Add", [d, "erode"], ["d_di"]),
             helper.make_node("Concat", [d, "d_er", "d_di"], ["low"], axis=1)]
    return nodes, inits


def sam2_decoder(path, layout="samexporter", with_orig=False, label_type=F32, scores_name="iou_predictions"):
    """SAM2 decoder whose masks are box distances: [d, d - 4, d + 4], IoU [.5, .9, .7]."""
    n1, i1 = box_distance_nodes("point_coords")
    n2, i2 = _multimask_nodes("d")
    inits = i1 + i2 + [const("iou", IOU)]
    if layout == "samexporter":
        inputs = [vi("image_embed", F32, [1, 3, 4, 4]), vi("high_res_feats_0", F32, [1, 3, 16, 16]),
                  vi("high_res_feats_1", F32, [1, 3, 8, 8]), vi("point_coords", F32, ["L", "P", 2]),
                  vi("point_labels", label_type, ["L", "P"]), vi("mask_input", F32, ["L", 1, LOW, LOW]),
                  vi("has_mask_input", F32, ["L"])]
        if with_orig:
            inputs.append(vi("orig_im_size", F32, [2]))
        nodes = n1 + n2 + [helper.make_node("Identity", ["low"], ["masks"]),
                           helper.make_node("Identity", ["iou"], [scores_name])]
        outputs = [vi("masks", F32, ["L", 3, LOW, LOW]), vi(scores_name, F32, ["L", 3])]
    else:
        inputs = [vi("image_features_0", F32, [1, 3, 16, 16]), vi("image_features_1", F32, [1, 3, 8, 8]),
                  vi("image_embeddings", F32, [1, 3, 4, 4]), vi("point_coords", F32, ["L", "P", 2]),
                  vi("point_labels", I32, ["L", "P"]), vi("input_masks", F32, ["L", 1, LOW, LOW]),
                  vi("has_input_masks", F32, ["L"]), vi("original_image_size", I32, [2])]
        inits += [const("s0", np.array([0], np.int64)), const("s2", np.array([2], np.int64))]
        nodes = n1 + n2 + [
            helper.make_node("Shape", ["low"], ["lowshape"]),
            helper.make_node("Slice", ["lowshape", "s0", "s2"], ["lm"]),
            helper.make_node("Cast", ["original_image_size"], ["hw"], to=I64),
            helper.make_node("Concat", ["lm", "hw"], ["sizes"], axis=0),
            helper.make_node("Resize", ["low", "", "", "sizes"], ["big"], mode="linear",
                             coordinate_transformation_mode="half_pixel"),
            helper.make_node("Constant", [], ["zero"], value=numpy_helper.from_array(np.array(0, np.float32))),
            helper.make_node("Greater", ["big", "zero"], ["masks"]),
            helper.make_node("Identity", ["iou"], ["iou_predictions"]),
            helper.make_node("Identity", ["low"], ["low_res_masks"]),
        ]
        outputs = [vi("masks", BOOL, ["L", 3, "H", "W"]), vi("iou_predictions", F32, ["L", 3]),
                   vi("low_res_masks", F32, ["L", 3, LOW, LOW])]
    return save(path, nodes, inputs, outputs, inits)


# ---------------------------------------------------------------- SAM2 video
# Encoder: pools of the image; decoder: "red pixels" mask (10 x normalised red).
def video_encoder(path):
    inits = [const("shp", np.array([1, 3, 16], np.int64)), const("zero", np.array(0, np.float32))]
    nodes = [pool("input", "image_embeddings", 16), pool("input", "high_res_features1", 4),
             pool("input", "high_res_features2", 8),
             helper.make_node("Identity", ["image_embeddings"], ["current_vision_feat"]),
             helper.make_node("Reshape", ["image_embeddings", "shp"], ["flat"]),
             helper.make_node("Transpose", ["flat"], ["tr"], perm=[2, 0, 1]),
             helper.make_node("Mul", ["tr", "zero"], ["vision_pos_embed"])]
    return save(path, nodes, [vi("input", F32, [1, 3, S, S])],
                [vi("image_embeddings", F32, [1, 3, 4, 4]), vi("high_res_features1", F32, [1, 3, 16, 16]),
                 vi("high_res_features2", F32, [1, 3, 8, 8]), vi("current_vision_feat", F32, [1, 3, 4, 4]),
                 vi("vision_pos_embed", F32, [16, 1, 3])], inits)


def video_decoder(path):
    inits = [const("st", np.array([0], np.int64)), const("en", np.array([1], np.int64)),
             const("ax", np.array([1], np.int64)), const("ten", np.array(10, np.float32)),
             const("msz", np.array([1, 1, S, S], np.int64)), const("twenty", np.array(20, np.float32)),
             const("mten", np.array(-10, np.float32))]
    nodes = [helper.make_node("Slice", ["high_res_feats_0", "st", "en", "ax"], ["red"]),
             helper.make_node("Mul", ["red", "ten"], ["pred_mask"]),
             helper.make_node("Resize", ["pred_mask", "", "", "msz"], ["hi"], mode="linear"),
             helper.make_node("Sigmoid", ["hi"], ["sg"]),
             helper.make_node("Mul", ["sg", "twenty"], ["sg20"]),
             helper.make_node("Add", ["sg20", "mten"], ["mask_for_mem"]),
             helper.make_node("ReduceMean", ["image_embed"], ["obj_ptr"], keepdims=0)]
    return save(path, nodes,
                [vi("point_coords", F32, ["L", "P", 2]), vi("point_labels", F32, ["L", "P"]),
                 vi("image_embed", F32, [1, 3, 4, 4]), vi("high_res_feats_0", F32, [1, 3, 16, 16]),
                 vi("high_res_feats_1", F32, [1, 3, 8, 8])],
                [vi("obj_ptr", F32, []), vi("mask_for_mem", F32, [1, 1, S, S]),
                 vi("pred_mask", F32, [1, 1, LOW, LOW])], inits)


def video_attention(path):
    """fused_feat = current_vision_feat; the graph still reshapes memory_pos_embed
    to (F, 16, 1, C) with F from memory_1, so a bank whose two tensors disagree fails."""
    inits = [const("s0", np.array([0], np.int64)), const("s1", np.array([1], np.int64)),
             const("rest", np.array([16, 1, -1], np.int64)), const("zero", np.array(0, np.float32))]
    nodes = [helper.make_node("Shape", ["memory_1"], ["m1s"]),
             helper.make_node("Slice", ["m1s", "s0", "s1"], ["nf"]),
             helper.make_node("Concat", ["nf", "rest"], ["tshape"], axis=0),
             helper.make_node("Reshape", ["memory_pos_embed", "tshape"], ["mp4"]),
             helper.make_node("ReduceSum", ["mp4"], ["mps"], keepdims=0),
             helper.make_node("ReduceSum", ["memory_1"], ["m1sum"], keepdims=0),
             helper.make_node("ReduceSum", ["memory_0"], ["m0sum"], keepdims=0),
             helper.make_node("Add", ["mps", "m1sum"], ["s_a"]),
             helper.make_node("Add", ["s_a", "m0sum"], ["s_b"]),
             helper.make_node("Mul", ["s_b", "zero"], ["z"]),
             helper.make_node("Add", ["current_vision_feat", "z"], ["fused_feat"])]
    return save(path, nodes,
                [vi("current_vision_feat", F32, [1, 3, 4, 4]), vi("current_vision_pos_embed", F32, [16, 1, 3]),
                 vi("memory_0", F32, ["n_ptr", 3]), vi("memory_1", F32, ["n_mem", 1, 4, 4]),
                 vi("memory_pos_embed", F32, ["buff", 1, 1])], [vi("fused_feat", F32, [1, 3, 4, 4])], inits)


def video_memory_encoder(path, n_mem=7):
    inits = [const("shp", np.array([1, 1, 16], np.int64)), const("zero", np.array(0, np.float32)),
             const("code", np.arange(n_mem, dtype=np.float32).reshape(n_mem, 1, 1, 1))]
    nodes = [pool("mask_for_mem", "maskmem_features", 16),
             helper.make_node("Reshape", ["maskmem_features", "shp"], ["flat"]),
             helper.make_node("Transpose", ["flat"], ["tr"], perm=[2, 0, 1]),
             helper.make_node("Mul", ["tr", "zero"], ["maskmem_pos_enc"]),
             helper.make_node("Identity", ["code"], ["temporal_code"])]
    return save(path, nodes, [vi("mask_for_mem", F32, [1, 1, S, S]), vi("pix_feat", F32, [1, 3, 4, 4])],
                [vi("maskmem_features", F32, [1, 1, 4, 4]), vi("maskmem_pos_enc", F32, [16, 1, 1]),
                 vi("temporal_code", F32, [n_mem, 1, 1, 1])], inits)


def video_set(tmp):
    tmp = Path(tmp)
    return dict(image_encoder=video_encoder(tmp / "image_encoder.onnx"),
                image_decoder=video_decoder(tmp / "image_decoder.onnx"),
                memory_attention=video_attention(tmp / "memory_attention.onnx"),
                memory_encoder=video_memory_encoder(tmp / "memory_encoder.onnx"))


# ---------------------------------------------------------------- tokenizers
BERT_VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", ".", "the", "red", "chair", "run", "##ning",
              "dog", "cafe", "table", "?", "left", "of", "##s"]


def bert_tokenizer_json(path):
    """A complete ``bert-base-uncased``-style tokenizer.json over BERT_VOCAB.

    Built with the ``tokenizers`` library the way ``BertTokenizerFast``
    saves it: BertNormalizer (lower-case, strip accents), BertPreTokenizer,
    WordPiece with ``##`` and the ``[CLS] $A [SEP]`` template.
    """
    from tokenizers import Tokenizer, models, normalizers, pre_tokenizers, processors

    tok = Tokenizer(models.WordPiece({t: i for i, t in enumerate(BERT_VOCAB)}, unk_token="[UNK]",
                                     max_input_chars_per_word=100))
    tok.normalizer = normalizers.BertNormalizer(clean_text=True, handle_chinese_chars=True,
                                                strip_accents=None, lowercase=True)
    tok.pre_tokenizer = pre_tokenizers.BertPreTokenizer()
    tok.post_processor = processors.TemplateProcessing(
        single="[CLS] $A [SEP]", pair="[CLS] $A [SEP] $B:1 [SEP]:1",
        special_tokens=[("[CLS]", 2), ("[SEP]", 3)])
    tok.save(str(path))
    return Path(path)


CLIP_VOCAB = ["!", "a", "c", "d", "e", "h", "i", "r", "a</w>", "d</w>", "r</w>", "ch", "cha", "chai",
              "chair</w>", "re", "red</w>", "ai", "t", "l", "b", "e</w>", "ta", "tab", "tabl", "table</w>",
              "<|startoftext|>", "<|endoftext|>"]
CLIP_MERGES = ["c h", "ch a", "cha i", "chai r</w>", "r e", "re d</w>", "a i", "t a", "ta b",
               "tab l", "tabl e</w>"]


def clip_tokenizer_json(path):
    """A complete CLIP tokenizer.json over CLIP_VOCAB, as ``CLIPTokenizerFast`` saves it.

    NFC + whitespace collapse + lower-case, CLIP's word split then
    byte-level, BPE with the ``</w>`` end-of-word suffix, start/end tokens.
    """
    from tokenizers import AddedToken, Regex, Tokenizer, decoders, models, normalizers, pre_tokenizers

    vocab = {t: i for i, t in enumerate(CLIP_VOCAB)}
    merges = [tuple(m.split(" ")) for m in CLIP_MERGES]
    tok = Tokenizer(models.BPE(vocab, merges, continuing_subword_prefix="", end_of_word_suffix="</w>",
                               fuse_unk=False, unk_token="<|endoftext|>"))
    tok.normalizer = normalizers.Sequence([normalizers.NFC(), normalizers.Replace(Regex(r"\s+"), " "),
                                           normalizers.Lowercase()])
    tok.pre_tokenizer = pre_tokenizers.Sequence([
        pre_tokenizers.Split(Regex(r"""'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""),
                             behavior="removed", invert=True),
        pre_tokenizers.ByteLevel(add_prefix_space=False)])
    tok.decoder = decoders.ByteLevel()
    tok.add_special_tokens([AddedToken("<|startoftext|>", special=True),
                            AddedToken("<|endoftext|>", special=True)])
    tok.save(str(path))
    return Path(path)


# ---------------------------------------------------------------- GroundingDINO
GDINO_BOXES = np.array([[[0.25, 0.5, 0.2, 0.4], [0.75, 0.5, 0.3, 0.6]]], np.float32)


def _token_hit_nodes(ids, token_ids, out, prefix="t"):
    """out (1, len(token_ids), L) = +10 where ids == token_ids[k] else -10."""
    nodes, inits, rows = [], [const(prefix + "twenty", np.array(20, np.float32)),
                              const(prefix + "ten", np.array(10, np.float32))], []
    for k, tid in enumerate(token_ids):
        inits.append(const(f"{prefix}id{k}", np.array(tid, np.int64)))
        nodes += [helper.make_node("Equal", [ids, f"{prefix}id{k}"], [f"{prefix}eq{k}"]),
                  helper.make_node("Cast", [f"{prefix}eq{k}"], [f"{prefix}f{k}"], to=F32),
                  helper.make_node("Mul", [f"{prefix}f{k}", prefix + "twenty"], [f"{prefix}m{k}"]),
                  helper.make_node("Sub", [f"{prefix}m{k}", prefix + "ten"], [f"{prefix}r{k}"])]
        rows.append(f"{prefix}r{k}")
    nodes.append(helper.make_node("Concat", rows, [out], axis=0 if len(rows) > 1 else 0))
    return nodes, inits


def grounding_dino(path, chair_id=7, table_id=12, layout="groundingdino", boxes=None):
    """Query 0 fires on the token 'chair', query 1 on 'table' (logits +-10).

    ``boxes``: (1, 2, 4) normalised (cx, cy, w, h) of the two queries
    (default :data:`GDINO_BOXES`), whatever the image.

    ``layout="transformers"``: the names of a transformers export
    (``pixel_values``, ``input_ids``, ``token_type_ids``, ``attention_mask``,
    ``pixel_mask`` -> ``logits``, ``pred_boxes``).
    """
    n, inits = _token_hit_nodes("input_ids", [chair_id, table_id], "hits")  # (2, L)
    inits += [const("ax0", np.array([0], np.int64)), const("s1", np.array([1], np.int64)),
              const("s2", np.array([2], np.int64)), const("n256", np.array([256], np.int64)),
              const("pad0", np.zeros(5, np.int64)), const("mten", np.array(-10, np.float32)),
              const("boxc", GDINO_BOXES if boxes is None else np.asarray(boxes, np.float32).reshape(1, 2, 4)),
              const("zero", np.array(0, np.float32))]
    n += [helper.make_node("Unsqueeze", ["hits", "ax0"], ["hits3"]),
          helper.make_node("Shape", ["input_ids"], ["ishape"]),
          helper.make_node("Slice", ["ishape", "s1", "s2"], ["L"]),
          helper.make_node("Sub", ["n256", "L"], ["padlen"]),
          helper.make_node("Concat", ["pad0", "padlen"], ["pads"], axis=0),
          helper.make_node("Pad", ["hits3", "pads", "mten"], ["raw"], mode="constant"),
          helper.make_node("ReduceMean", ["img" if layout == "groundingdino" else "pixel_values"], ["imean"],
                           keepdims=0),
          helper.make_node("Cast", ["text_token_mask" if layout == "groundingdino" else "pixel_mask"], ["tmf"],
                           to=F32),
          helper.make_node("ReduceSum", ["tmf"], ["tms"], keepdims=0),
          helper.make_node("Add", ["imean", "tms"], ["junk"]),
          helper.make_node("Mul", ["junk", "zero"], ["z"]),
          helper.make_node("Add", ["raw", "z"], ["logits"]),
          helper.make_node("Add", ["boxc", "z"], ["boxes" if layout == "groundingdino" else "pred_boxes"])]
    if layout == "transformers":
        return save(path, n,
                    [vi("pixel_values", F32, [1, 3, "H", "W"]), vi("input_ids", I64, [1, "L"]),
                     vi("token_type_ids", I64, [1, "L"]), vi("attention_mask", I64, [1, "L"]),
                     vi("pixel_mask", I64, [1, "H", "W"])],
                    [vi("logits", F32, [1, 2, 256]), vi("pred_boxes", F32, [1, 2, 4])], inits)
    return save(path, n,
                [vi("img", F32, [1, 3, "H", "W"]), vi("input_ids", I64, [1, "L"]),
                 vi("attention_mask", BOOL, [1, "L"]), vi("position_ids", I64, [1, "L"]),
                 vi("token_type_ids", I64, [1, "L"]), vi("text_token_mask", BOOL, [1, "L", "L"])],
                [vi("logits", F32, [1, 2, 256]), vi("boxes", F32, [1, 2, 4])], inits)


# ---------------------------------------------------------------- SAM3 (samexporter layout)
S3 = 32
CHAIR_CLIP, TABLE_CLIP = 14, 25          # ids of "chair</w>", "table</w>" in CLIP_VOCAB
SAM3_BOXES = np.array([[[0.25, 0.5, 0.3, 0.4], [0.7, 0.5, 0.3, 0.6]]], np.float32)


def _box_logits(boxes, n=8):
    c = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(c, c)
    out = []
    for cx, cy, w, h in boxes:
        inside = (np.abs(X - cx) < w / 2) & (np.abs(Y - cy) < h / 2)
        out.append(np.where(inside, 5.0, -5.0))
    return np.asarray(out, np.float32)[None]


def sam3_image_encoder(path, dtype=U8):
    names = ["vision_pos_enc_0", "vision_pos_enc_1", "vision_pos_enc_2",
             "backbone_fpn_0", "backbone_fpn_1", "backbone_fpn_2"]
    nodes = [helper.make_node("Cast", ["image"], ["fimg"], to=F32),
             helper.make_node("Unsqueeze", ["fimg", "ax0"], ["bimg"]),
             pool("bimg", "feat", 8)] + [helper.make_node("Identity", ["feat"], [n]) for n in names]
    return save(path, nodes, [vi("image", dtype, [3, S3, S3])],
                [vi(n, F32, [1, 3, 4, 4]) for n in names], [const("ax0", np.array([0], np.int64))])


def sam3_language_encoder(path):
    inits = [const("zero64", np.array(0, np.int64)), const("shp", np.array([32, 1, 1], np.int64))]
    nodes = [helper.make_node("Equal", ["tokens", "zero64"], ["text_attention_mask"]),
             helper.make_node("Cast", ["tokens"], ["tf"], to=F32),
             helper.make_node("Reshape", ["tf", "shp"], ["text_memory"]),
             helper.make_node("Identity", ["text_memory"], ["text_embeds"])]
    return save(path, nodes, [vi("tokens", I64, [1, 32])],
                [vi("text_attention_mask", BOOL, [1, 32]), vi("text_memory", F32, [32, 1, 1]),
                 vi("text_embeds", F32, [32, 1, 1])], inits)


def sam3_decoder(path, capacity=None):
    """Query 0 (left box) fires on 'chair', query 1 (right box) on 'table'; any box prompt fires both."""
    inits = [const("cid", np.array(CHAIR_CLIP, np.float32)), const("tid", np.array(TABLE_CLIP, np.float32)),
             const("twenty", np.array(20, np.float32)), const("ten", np.array(10, np.float32)),
             const("shp", np.array([1, 1, 1], np.int64)), const("boxc", SAM3_BOXES),
             const("maskc", _box_logits(SAM3_BOXES[0])), const("pres", np.array([[10.0]], np.float32)),
             const("zero", np.array(0, np.float32))]
    nodes = []
    for q, tid in (("0", "cid"), ("1", "tid")):
        nodes += [helper.make_node("Equal", ["language_features", tid], ["eq" + q]),
                  helper.make_node("Cast", ["eq" + q], ["eqf" + q], to=F32),
                  helper.make_node("ReduceMax", ["eqf" + q], ["hit" + q], keepdims=0)]
    nodes += [helper.make_node("Not", ["box_masks"], ["valid"]),
              helper.make_node("Cast", ["valid"], ["validf"], to=F32),
              helper.make_node("ReduceMax", ["validf"], ["anybox"], keepdims=0),
              helper.make_node("Max", ["hit0", "anybox"], ["h0"]),
              helper.make_node("Max", ["hit1", "anybox"], ["h1"]),
              helper.make_node("Reshape", ["h0", "shp"], ["h0r"]),
              helper.make_node("Reshape", ["h1", "shp"], ["h1r"]),
              helper.make_node("Concat", ["h0r", "h1r"], ["hits"], axis=1),
              helper.make_node("Mul", ["hits", "twenty"], ["h20"]),
              helper.make_node("Sub", ["h20", "ten"], ["lg"]),
              # consume the remaining inputs so their shapes are exercised
              helper.make_node("Cast", ["original_height"], ["ohf"], to=F32),
              helper.make_node("ReduceSum", ["backbone_fpn_2"], ["bsum"], keepdims=0),
              helper.make_node("ReduceSum", ["box_coords"], ["csum"], keepdims=0),
              helper.make_node("Add", ["ohf", "bsum"], ["j1"]),
              helper.make_node("Add", ["j1", "csum"], ["j2"]),
              helper.make_node("Mul", ["j2", "zero"], ["z"]),
              helper.make_node("Add", ["lg", "z"], ["pred_logits"]),
              helper.make_node("Add", ["boxc", "z"], ["pred_boxes"]),
              helper.make_node("Add", ["maskc", "z"], ["pred_masks"]),
              helper.make_node("Identity", ["pres"], ["presence_logit_dec"])]
    k = capacity or "K"
    ins = [vi("original_height", I64, []), vi("original_width", I64, [])]
    ins += [vi(f"vision_pos_enc_{i}", F32, [1, 3, 4, 4]) for i in range(3)]
    ins += [vi(f"backbone_fpn_{i}", F32, [1, 3, 4, 4]) for i in range(3)]
    ins += [vi("language_mask", BOOL, [1, 32]), vi("language_features", F32, [32, 1, 1]),
            vi("language_embeds", F32, [32, 1, 1]), vi("box_coords", F32, [k, 1, 4]),
            vi("box_labels", I64, [k, 1]), vi("box_masks", BOOL, [1, k])]
    return save(path, nodes, ins,
                [vi("pred_logits", F32, [1, 2, 1]), vi("pred_boxes", F32, [1, 2, 4]),
                 vi("pred_masks", F32, [1, 2, 8, 8]), vi("presence_logit_dec", F32, [1, 1])], inits)


def sam3_set(tmp):
    tmp = Path(tmp)
    return dict(image_encoder=sam3_image_encoder(tmp / "sam3_enc.onnx"),
                language_encoder=sam3_language_encoder(tmp / "sam3_lang.onnx"),
                decoder=sam3_decoder(tmp / "sam3_dec.onnx"),
                tokenizer=clip_tokenizer_json(tmp / "clip_tokenizer.json"))


# ---------------------------------------------------------------- OWL-ViT (optimum layout)
OWL_BOXES = np.array([[[0.3, 0.3, 0.2, 0.2], [0.6, 0.7, 0.4, 0.3]]], np.float32)


def owlvit(path):
    """Patch 0 fires on 'chair', patch 1 on 'table' (logits +-10); fixed boxes."""
    inits = [const("twenty", np.array(20, np.float32)), const("ten", np.array(10, np.float32)),
             const("boxc", OWL_BOXES), const("zero", np.array(0, np.float32)),
             const("shp", np.array([1, 1, 1], np.int64))]
    nodes, rows = [], []
    for q, tid in (("0", CHAIR_CLIP), ("1", TABLE_CLIP)):
        inits.append(const("id" + q, np.array(tid, np.int64)))
        nodes += [helper.make_node("Equal", ["input_ids", "id" + q], ["eq" + q]),
                  helper.make_node("Cast", ["eq" + q], ["eqf" + q], to=F32),
                  helper.make_node("ReduceMax", ["eqf" + q], ["hit" + q], keepdims=0),
                  helper.make_node("Reshape", ["hit" + q, "shp"], ["r" + q])]
        rows.append("r" + q)
    nodes += [helper.make_node("Concat", rows, ["hits"], axis=1),
              helper.make_node("Mul", ["hits", "twenty"], ["h20"]),
              helper.make_node("Sub", ["h20", "ten"], ["lg"]),
              helper.make_node("ReduceMean", ["pixel_values"], ["pm"], keepdims=0),
              helper.make_node("Cast", ["attention_mask"], ["amf"], to=F32),
              helper.make_node("ReduceSum", ["amf"], ["ams"], keepdims=0),
              helper.make_node("Add", ["pm", "ams"], ["j"]),
              helper.make_node("Mul", ["j", "zero"], ["z"]),
              helper.make_node("Add", ["lg", "z"], ["logits"]),
              helper.make_node("Add", ["boxc", "z"], ["pred_boxes"])]
    return save(path, nodes, [vi("input_ids", I64, ["nq", 16]), vi("pixel_values", F32, [1, 3, 32, 32]),
                              vi("attention_mask", I64, ["nq", 16])],
                [vi("logits", F32, [1, 2, "nq"]), vi("pred_boxes", F32, [1, 2, 4])], inits)


# ---------------------------------------------------------------- SAM (v1), samexporter layout
SAM_IOU = np.array([[0.99, 0.5, 0.9, 0.7]], np.float32)   # mask 0 (single-mask token) is excluded


def sam_encoder(path):
    """``input_image`` (H', W', 3) -> ``image_embeddings`` (1, 3, 4, 4) = the image mean everywhere."""
    inits = [const("shape", np.array([1, 3, 4, 4], np.int64))]
    nodes = [helper.make_node("ReduceMean", ["input_image"], ["m"], keepdims=1),
             helper.make_node("Expand", ["m", "shape"], ["image_embeddings"])]
    return save(path, nodes, [vi("input_image", F32, ["h", "w", 3])],
                [vi("image_embeddings", F32, [1, 3, 4, 4])], inits)


def sam_decoder(path):
    """segment-anything's SamOnnxModel names; ``low_res_masks`` = [d, d - 4, d + 4, d - 4]
    (box distance on the LOW grid of the S x S frame), ``masks`` all -1 (as a broken in-graph
    post-processing would be: the host must use ``low_res_masks``)."""
    n1, i1 = box_distance_nodes("point_coords")
    n2, i2 = _multimask_nodes("d")
    inits = i1 + i2 + [const("iou", SAM_IOU), const("minus1", np.array(-1.0, np.float32)),
                       const("zero_f", np.array(0.0, np.float32))]
    nodes = n1 + n2 + [
        helper.make_node("Concat", ["low", "d_er"], ["low_res_masks"], axis=1),
        helper.make_node("Identity", ["iou"], ["iou_predictions"]),
        helper.make_node("Mul", ["low_res_masks", "zero_f"], ["z"]),
        helper.make_node("Add", ["z", "minus1"], ["masks"])]
    inputs = [vi("image_embeddings", F32, [1, 3, 4, 4]), vi("point_coords", F32, [1, "P", 2]),
              vi("point_labels", F32, [1, "P"]), vi("mask_input", F32, [1, 1, LOW, LOW]),
              vi("has_mask_input", F32, [1]), vi("orig_im_size", F32, [2])]
    outputs = [vi("masks", F32, [1, 4, LOW, LOW]), vi("iou_predictions", F32, [1, 4]),
               vi("low_res_masks", F32, [1, 4, LOW, LOW])]
    return save(path, nodes, inputs, outputs, inits)
