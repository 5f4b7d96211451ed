"""Runtime: stage contract, run folder, commit protocol and markers, table I/O, status, locks, executors (inline and Ray)."""
