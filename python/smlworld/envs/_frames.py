"""What every smlworld env shares: the ``rgb_array`` frame of its simulation."""

from __future__ import annotations

import numpy as np

#: Size of an env's ``rgb_array`` frame (width, height) [px].
FRAME_SIZE = (640, 360)


def rgb_frame(env):
    """With ``render_mode="rgb_array"``: the bird's-eye view of ``env._sim`` now, an (H, W, 3)
    uint8 array (640 x 360) from the off-screen renderer; ``None`` without a render mode or
    before ``reset()``."""
    if env.render_mode != "rgb_array" or env._sim is None:
        return None
    width, height = FRAME_SIZE
    return np.ascontiguousarray(env._sim.frame(width=width, height=height)[..., :3])
