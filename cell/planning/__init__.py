"""Planning for the CloPeMa cell: kinematics (IK), collision checking, motion and fold planning.

Entry points: `FoldPlanner.plan_fold(category, fold_index, landmarks_table, q_current) -> FoldPlan`
(cell/planning/folds.py) and `MotionPlanner` (free moves, Cartesian moves, `perceive_move`)
(cell/planning/motion.py). Errors: cell/planning/errors.py. Settings: config/planning.yaml.
"""
