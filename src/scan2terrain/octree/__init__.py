"""The voxel octree: OctoMap's probabilistic model, ray casting, queries and .bt files."""
