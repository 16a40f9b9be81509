"""Sensors drawn from a world snapshot: the ego-centred BEV raster (``bev``) and its compiled
pixel kernels (``bev_pixels``). The same renderer serves the closed loop and training."""
