"""Digital twin of the three-section PMA arm: MuJoCo physics, offscreen stereo rendering, exact truth."""
