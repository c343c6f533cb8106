"""The 3-D finite-element finger on NGSolve (optional extra, offline: no node imports it)."""
