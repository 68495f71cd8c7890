"""foldcell cell package."""
