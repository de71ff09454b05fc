"""Rendering SparseBTF materials: a Mitsuba 3 BSDF plugin and a WebGL viewer."""
