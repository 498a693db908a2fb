"""The worlds: towns as scenes of parts (layout, feature modules on a shared builder, meshes, textures, styles), traffic, the world cache. Imports no GL."""
