"""Math kernels in NumPy; each formula that also lives in kernels/*.h is tested against it.

Modules here import nothing else from the project."""
