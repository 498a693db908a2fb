"""The output root's contract: what marks a root, leases, the run record (run.json), the job spec, verify."""
