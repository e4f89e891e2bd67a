"""Pure NumPy/SciPy core of the delighting tool (never imports bpy)."""
