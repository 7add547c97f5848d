"""Once per character: tet mesh, regions, weights, constraints, on-disk cache."""
