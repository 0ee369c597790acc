"""planning package (see DESIGN.md)."""
