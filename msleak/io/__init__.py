"""File formats: Measurement Sets, FITS cubes, sky models and msleak's own products."""
