"""The built-in rendering methods, one folder each (a descriptor in its ``__init__.py``;
pipeline/registry.py finds them and the plug-ins named by ``PRT_PLUGINS``)."""
