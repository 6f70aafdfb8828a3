"""msleak.telescope."""
