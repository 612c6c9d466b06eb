"""Method sg's stages (declared in pipeline/methods/sg/stages.yaml)."""
