"""Runtime: stage contract, run folder, markers, status, locks and the Ray executor."""
