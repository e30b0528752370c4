"""Small programs: `simulate` (the headless run), `describe` (a scene's URDF) and the kernel
warm-up. The larger ones have folders of their own (node, replay, plot, sweep, bench)."""
