"""The compiled bitmap lookup (common.kernels.texture) equals the numpy formulation it replaced
bit for bit: bilinear and nearest, any uv (negative, huge, exactly on texel edges), scales and
offsets, 1-pixel and non-square images."""
from __future__ import annotations

import numpy as np
import pytest

from igi.common.scene import Texture
from tests.support.oracle_texture import texture_eval


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (5, 3), (64, 48)])
@pytest.mark.parametrize("filt", ["bilinear", "nearest"])
@pytest.mark.parametrize("scale, offset", [((1.0, 1.0), (0.0, 0.0)), ((3.5, -2.0), (0.25, 7.0))])
def test_lookup_equals_the_numpy_formulation(shape, filt, scale, offset):
    rng = np.random.default_rng(sum(shape))
    img = rng.random((*shape, 3)).astype(np.float32)
    tex = Texture(image=img, filter=filt, uv_scale=scale, uv_offset=offset)
    uv = np.concatenate([rng.uniform(-3, 3, (500, 2)), rng.uniform(-1e6, 1e6, (50, 2)),
                         np.array([[0.0, 0.0], [1.0, 1.0], [0.5, 0.5], [-0.0, 1e-300], [1 - 1e-16, 0.25]]),
                         (np.arange(20)[:, None] + 0.5) / np.array(shape[::-1])[None, :]])
    got = tex.eval(uv)
    assert got.dtype == np.float32 and got.shape == (len(uv), 3)
    np.testing.assert_array_equal(got, texture_eval(tex, uv))


def test_empty_lookup_and_constant_textures():
    img = np.ones((2, 2, 3), np.float32)
    assert Texture(image=img).eval(np.zeros((0, 2))).shape == (0, 3)
    np.testing.assert_array_equal(Texture.constant([0.1, 0.2, 0.3]).eval(np.zeros((2, 2))),
                                  np.float32([[0.1, 0.2, 0.3]] * 2))
