"""estimation package (see DESIGN.md)."""
