"""The cell state machine (no Zenoh): sequencing of perceive, match, plan, grasp, fold, verify."""
