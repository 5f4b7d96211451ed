"""Runtime: the stage contract, one unit's attempt, executors (inline and Ray), the runner, the status table
and the run's state. It speaks to the run's bytes only through `pipeline.store.RunFolder`."""
