"""foldcell tools package."""
