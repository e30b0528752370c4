"""Run-time services every program shares: the run's time line, pacing against the wall clock,
the headless run, progress on a terminal, the executables' error handling, memory."""
