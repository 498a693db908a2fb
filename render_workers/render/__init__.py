"""Rendering an episode off-screen: the pyrender renderer and its patches, shaders, camera rig, sky, post effects, instances; an episode gives named buffers."""
