"""Scoring perception and folds against references: datasets, logged sessions, ideal folds."""
