"""Photogrammetry: a pinhole camera with lens distortion, fiducial tags on rigid bodies, and the
bundle adjustment that places the bodies in the article's frame from photographs."""
