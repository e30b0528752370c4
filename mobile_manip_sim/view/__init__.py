"""The browser view: the robot drawn from its URDF in a local web page, moving — live or from a
recorded run — beside its energy and impacts (`browser`; what to draw: `drawing`; a recorded
run: `recorded`)."""
