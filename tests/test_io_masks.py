"""io.read_masks: a directory of per-view masks, and clear errors naming the bad file."""

import numpy as np
import pytest
from PIL import Image

from seed2gs_inverse.errors import FormatError, ValidationError
from seed2gs_inverse.io import read_masks


def _png(path, arr, mode="L"):
    Image.fromarray(arr, mode=mode).save(path)


def test_reads_png_in_view_order(tmp_path):
    masks = [np.full((4, 6), 255 * (k % 2), np.uint8) for k in range(12)]
    masks[3][1, 2] = 255
    for k, m in enumerate(masks):
        _png(tmp_path / f"view_{k:03d}.png", m)
    (tmp_path / "notes.txt").write_text("ignored")
    out = read_masks(tmp_path, n_views=12, image_shapes=[(4, 6)] * 12)
    assert len(out) == 12
    for a, b in zip(out, masks):  # view_010 after view_009, not after view_001
        assert a.dtype == np.uint8 and np.array_equal(a, b)


def test_colour_png_becomes_grey(tmp_path):
    rgb = np.zeros((3, 5, 3), np.uint8)
    rgb[1, 1] = 255
    _png(tmp_path / "view_000.png", rgb, "RGB")
    (out,) = read_masks(tmp_path)
    assert out.shape == (3, 5) and out[1, 1] == 255 and out.sum() == 255


def test_reads_npy_as_stored(tmp_path):
    a = np.array([[0.0, np.nan], [0.25, 1.0]], np.float32)
    b = np.array([[True, False], [False, True]])
    flat = np.array([0, 1, 1, 0], np.uint8)  # flat (H*W,) pixels are accepted, as by the solvers
    for k, m in enumerate([a, b, flat]):
        np.save(tmp_path / f"view_{k}.npy", m)
    out = read_masks(tmp_path, 3, [(2, 2)] * 3)
    assert out[0].dtype == np.float32 and np.array_equal(out[0], a, equal_nan=True)
    assert out[1].dtype == bool and np.array_equal(out[1], b)
    assert np.array_equal(out[2], flat)


def test_wrong_size_names_the_file(tmp_path):
    _png(tmp_path / "view_000.png", np.zeros((4, 6), np.uint8))
    _png(tmp_path / "view_001.png", np.zeros((5, 6), np.uint8))
    with pytest.raises(ValidationError, match=r"view_001\.png.*\(5, 6\).*view 1 is \(4, 6\)"):
        read_masks(tmp_path, 2, [(4, 6), (4, 6)])


def test_not_an_image_names_the_file(tmp_path):
    _png(tmp_path / "view_000.png", np.zeros((4, 6), np.uint8))
    (tmp_path / "view_001.png").write_bytes(b"this is not a png")
    with pytest.raises(FormatError, match=r"view_001\.png: not a readable PNG"):
        read_masks(tmp_path)


def test_corrupt_npy_names_the_file(tmp_path):
    (tmp_path / "view_000.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(FormatError, match=r"view_000\.npy: not a readable \.npy"):
        read_masks(tmp_path)


@pytest.mark.parametrize("arr, what", [(np.array([["a", "b"]]), "dtype"),
                                       (np.zeros((2, 2, 2), np.float32), "shape"),
                                       (np.zeros((0,), np.float32), "shape")])
def test_bad_npy_content_names_the_file(tmp_path, arr, what):
    np.save(tmp_path / "view_000.npy", arr)
    with pytest.raises(FormatError, match=rf"view_000\.npy: .*{what}"):
        read_masks(tmp_path)


def test_views_may_mix_formats(tmp_path):
    # Accepted as before the move (the CLI test writes PNG and .npy views side by side).
    _png(tmp_path / "view_000.png", np.full((4, 6), 255, np.uint8))
    np.save(tmp_path / "view_001.npy", np.full((4, 6), np.nan, np.float32))
    a, b = read_masks(tmp_path, 2, [(4, 6)] * 2)
    assert a.dtype == np.uint8 and np.all(a == 255) and b.dtype == np.float32 and np.all(np.isnan(b))


def test_one_view_in_two_formats_names_both_files(tmp_path):
    _png(tmp_path / "view_000.png", np.zeros((4, 6), np.uint8))
    np.save(tmp_path / "view_000.npy", np.zeros((4, 6), np.float32))
    with pytest.raises(FormatError, match=r"two masks for view 0 \(view_000\.(png|npy), view_000\.(npy|png)\)"):
        read_masks(tmp_path)


def test_missing_view_is_named(tmp_path):
    for k in (0, 1, 3):
        _png(tmp_path / f"view_{k:03d}.png", np.zeros((4, 6), np.uint8))
    with pytest.raises(FormatError, match=r"without gaps; view\(s\) 2 missing below view_003.png"):
        read_masks(tmp_path)


def test_a_mask_beyond_the_views_is_named(tmp_path):
    """One extra file used to read "numbered 0..8; missing view(s) [8, 9, 10, 11]"."""
    for k in (0, 1, 2, 12):
        _png(tmp_path / f"view_{k:03d}.png", np.zeros((4, 6), np.uint8))
    with pytest.raises(ValidationError, match=r"view_012.png names a view beyond the 3 operator views "
                                              r"\(view_000 .. view_002\); remove or renumber it"):
        read_masks(tmp_path, n_views=3)


def test_two_files_for_one_view(tmp_path):
    _png(tmp_path / "view_000.png", np.zeros((4, 6), np.uint8))
    _png(tmp_path / "view_0.png", np.zeros((4, 6), np.uint8))
    with pytest.raises(FormatError, match="two masks for view 0"):
        read_masks(tmp_path)


def test_count_must_match_views(tmp_path):
    _png(tmp_path / "view_000.png", np.zeros((4, 6), np.uint8))
    with pytest.raises(ValidationError, match="1 masks for 2 operator views"):
        read_masks(tmp_path, n_views=2)
    with pytest.raises(ValidationError, match="1 masks for 2 image shapes"):
        read_masks(tmp_path, image_shapes=[(4, 6), (4, 6)])


def test_not_a_directory_or_empty(tmp_path):
    with pytest.raises(FormatError, match="not a directory"):
        read_masks(tmp_path / "nope")
    with pytest.raises(FormatError, match="no masks named"):
        read_masks(tmp_path)


def test_huge_view_numbers_cost_nothing(tmp_path):
    """A gap report only looks below the number of files: one view_99999999 must not build a set of
    a hundred million numbers (it used gigabytes, or got the process killed)."""
    np.save(tmp_path / "view_000.npy", np.zeros((4, 6)))
    np.save(tmp_path / "view_99999999999999999999.npy", np.zeros((4, 6)))
    with pytest.raises(FormatError, match=r"view\(s\) 1, 2, 3, 4, 5, \.\.\. missing below "
                                          r"view_99999999999999999999\.npy"):
        read_masks(tmp_path)


def test_npy_header_promising_more_than_the_file_holds(tmp_path):
    """A 128-byte .npy claiming 10^11 float64 is refused from its header, before numpy allocates 745 GiB."""
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (100000000000,), }"
    header += " " * (118 - len(header)) + "\n"
    (tmp_path / "view_000.npy").write_bytes(b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little")
                                            + header.encode())
    with pytest.raises(FormatError, match=r"view_000\.npy: the header promises 800000000000 bytes of data but "
                                          r"the file holds 0"):
        read_masks(tmp_path)


def test_decompression_bomb_is_a_format_error(tmp_path):
    Image.new("1", (20000, 20000)).save(tmp_path / "view_000.png")  # 400 M pixels in a few KB
    with pytest.raises(FormatError, match=r"view_000\.png: the PNG declares more than 134217728 pixels, "
                                          r"the limit .*decompression bomb"):
        read_masks(tmp_path)


def test_png_that_is_not_lossless_greyscale_content(tmp_path):
    mask = np.zeros((4, 6), np.uint8)
    mask[1:3, 2:5] = 255
    Image.fromarray(mask).save(tmp_path / "view_000.png", format="JPEG")
    with pytest.raises(FormatError, match=r"view_000\.png: a JPEG image under a \.png name"):
        read_masks(tmp_path)
    cutout = np.zeros((4, 6, 4), np.uint8)
    cutout[..., 3] = mask  # the object in the alpha channel, black colour everywhere
    Image.fromarray(cutout, "RGBA").save(tmp_path / "view_000.png")
    with pytest.raises(FormatError, match="transparency marks other pixels than its grey values"):
        read_masks(tmp_path)
    opaque = np.dstack([mask] * 3 + [np.full((4, 6), 255, np.uint8)])  # an opaque RGBA mask reads as its grey
    Image.fromarray(opaque, "RGBA").save(tmp_path / "view_000.png")
    np.testing.assert_array_equal(read_masks(tmp_path)[0], mask)
    Image.fromarray(mask).save(tmp_path / "view_000.png", transparency=0)  # greyscale, black transparent
    np.testing.assert_array_equal(read_masks(tmp_path)[0], mask)


def test_gap_report_names_the_missing_views(tmp_path):
    for k in (0, 1, 5):
        np.save(tmp_path / f"view_{k:03d}.npy", np.zeros((4, 6)))
    with pytest.raises(FormatError, match=r"view\(s\) 2, 3, 4 missing below view_005\.npy"):
        read_masks(tmp_path)


@pytest.mark.parametrize("kw, what", [({"n_views": "2"}, "n_views"), ({"n_views": 0}, "n_views"),
                                      ({"image_shapes": [("a", 2)]}, "image_shapes"),
                                      ({"image_shapes": [None]}, "image_shapes"),
                                      ({"image_shapes": [(4, 6, 1)]}, "image_shapes")])
def test_bad_arguments_are_named(tmp_path, kw, what):
    np.save(tmp_path / "view_000.npy", np.zeros((4, 6)))
    with pytest.raises(ValidationError, match=f"read_masks: {what} must be"):
        read_masks(tmp_path, **kw)
