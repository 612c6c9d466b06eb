"""Method d2i's stages (declared in pipeline/methods/d2i/stages.yaml)."""
