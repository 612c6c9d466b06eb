"""The stages every method may read (declared in the project's stages.yaml): ``geometry``
(the scene's meshes merged in world space) and ``gbuffer`` (one camera ray per pixel).
What a stage module provides, and what the runner gives it: pipeline/engine/stage.py."""
