"""prt-pipeline: precomputed light transport bake pipeline and OpenCL relighting renderer."""

__version__ = "0.1.0"
