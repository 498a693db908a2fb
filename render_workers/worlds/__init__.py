"""The worlds: towns as scenes of parts (layout, feature modules, kit, meshes, textures, styles), traffic, the world cache. Imports no GL."""
