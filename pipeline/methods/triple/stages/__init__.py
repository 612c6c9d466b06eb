"""Method triple's stages (declared in pipeline/methods/triple/stages.yaml)."""
