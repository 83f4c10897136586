"""Evaluation, split by job: `rollout` (the one episode loop), `reference` (the privileged servo behind
SPL), `protocol` (fixed seeds, metrics per episode), `perturbation` (push the arm away after focus) and
`report` (tables, JSON, plots). The metrics themselves are `mani_active_vision.metrics`."""
