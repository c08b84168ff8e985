"""Makes ripples.png (a normal map) and dimples.png (a height map) for bump.xml (CC0)."""
import numpy as np
from PIL import Image

n = 128
x = (np.arange(n) + 0.5) / n
u, v = np.meshgrid(x, x)  # (row, column): v runs down the image
# ripples: slopes along u (3 periods) and, weaker, along the image's rows (2 periods)
nx = -0.45 * np.cos(2 * np.pi * 3 * u)
ny = -0.25 * np.cos(2 * np.pi * 2 * v)
nrm = np.stack([nx, ny, np.ones_like(nx)], -1)
nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
Image.fromarray(np.round((nrm * 0.5 + 0.5) * 255).astype(np.uint8), "RGB").save("ripples.png")
# dimples: a smooth height field (4 x 4 bumps), 16-bit grey
h = 0.5 + 0.5 * np.sin(2 * np.pi * 4 * u) * np.sin(2 * np.pi * 4 * v)
Image.fromarray(np.round(h * 65535).astype(np.uint16)).save("dimples.png")
