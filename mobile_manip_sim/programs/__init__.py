"""Small programs: `simulate` (the headless run) and `describe` (a scene's URDF). The larger
ones have folders of their own (node, replay, plot, sweep, bench)."""
