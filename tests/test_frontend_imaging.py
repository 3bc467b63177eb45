"""Pillow-exact resampling of the front end against Pillow itself (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seed2gs_inverse.errors import ValidationError
from seed2gs_inverse.frontend._imaging import resample


@pytest.mark.parametrize("size", [(80, 120), (20, 30), (16, 53), (37, 10)])
@pytest.mark.parametrize("kernel", ["bilinear", "bicubic"])
def test_resample_matches_pillow_8bit(rng, size, kernel):
    """Enlarging and shrinking (anti-aliased) in 8-bit as Pillow: its fixed-point taps
    may round a grey level differently."""
    img = np.round(rng.random((37, 53, 3)) * 255).astype(np.uint8)
    how = Image.BILINEAR if kernel == "bilinear" else Image.BICUBIC
    ref = np.asarray(Image.fromarray(img).resize((size[1], size[0]), how), np.float64)
    ours = resample(img / 255.0, size, kernel, eight_bit=True) * 255.0
    assert ours.shape == size + (3,)
    assert np.abs(ours - ref).max() <= 1.0 + 1e-4


def test_resample_float_is_plain_bilinear_when_enlarging(rng):
    """Without eight_bit and when enlarging: half-pixel bilinear with clamped borders
    (torch interpolate(align_corners=False)), computed here by brute force."""
    img = rng.random((5, 7, 1)).astype(np.float32)
    out = resample(img, (10, 21))[:, :, 0]
    ys = np.clip((np.arange(10) + 0.5) * 5 / 10 - 0.5, 0, 4)
    xs = np.clip((np.arange(21) + 0.5) * 7 / 21 - 0.5, 0, 6)
    y0, x0 = np.floor(ys).astype(int), np.floor(xs).astype(int)
    y1, x1 = np.minimum(y0 + 1, 4), np.minimum(x0 + 1, 6)
    wy, wx = (ys - y0)[:, None], (xs - x0)[None, :]
    a = img[:, :, 0]
    want = ((1 - wy) * ((1 - wx) * a[y0][:, x0] + wx * a[y0][:, x1])
            + wy * ((1 - wx) * a[y1][:, x0] + wx * a[y1][:, x1]))
    np.testing.assert_allclose(out, want, atol=1e-6)


def test_resample_rejects_bad_input():
    with pytest.raises(ValidationError, match="unknown filter"):
        resample(np.zeros((4, 4, 3)), (2, 2), "nearest")
    with pytest.raises(ValidationError, match="expected"):
        resample(np.zeros((4, 4)), (2, 2))
