"""The scene: its model (model), its file format and validation (file), run-time edits
(edits) and the mesh files it names (meshio)."""
