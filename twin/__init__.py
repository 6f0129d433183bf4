"""Digital twin of the three-section PMA arm: MuJoCo physics, offscreen stereo rendering, exact truth.

``from twin import Twin`` loads the physics and the renderer; importing the package alone does
not (the bench's rig branch imports nothing from here).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from twin.twin import Twin

__all__ = ["Twin"]


def __getattr__(name: str):
    if name == "Twin":
        from twin.twin import Twin

        return Twin
    raise AttributeError(f"module 'twin' has no attribute {name!r}")
