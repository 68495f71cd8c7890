"""foldcell statemachine package."""
