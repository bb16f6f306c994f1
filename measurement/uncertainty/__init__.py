"""Uncertainty of stereo-DIC results: the parts each error source contributes to a measured point."""
