"""Cloth physics for the simulated world: a MuJoCo flex cloth on the table, folded by two grippers."""
