"""Built-in method plug-ins: every module here defines ``METHOD = Method(...)``
(pipeline/method.py). The core reads them through the registry and names none."""
