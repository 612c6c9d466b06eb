#!/usr/bin/env bash
# Prepare benchmarks/device_run.sh on this machine, before a device session's first call:
# the project's wheels for the device machine's Python 3.12 (cp312 manylinux x86-64, at
# the versions this checkout's .venv runs, `pip download --no-deps`) into .whl/, and the
# shared data files the project names (../shared/data, or $PRT_DATA) into .devdata/; both
# folders are added to .git/info/exclude. Name both in the run's carry: ≈ 46 MB
# together, which with the working tree (≈ 18 MB) is just inside the 64 MiB a call may
# carry. Usage, from anywhere: benchmarks/device_prepare.sh (≈ 20 s).
set -eu
cd "$(dirname "$0")/.."
py=${PYTHON:-.venv/bin/python}
exclude=$(git rev-parse --git-path info/exclude)
mkdir -p "$(dirname "$exclude")"
for folder in /.whl/ /.devdata/; do
    grep -qxF "$folder" "$exclude" 2>/dev/null || echo "$folder" >>"$exclude"
done
# What the device machine's image lacks (/work/.library/device/KINDS.md lists what it
# has: NumPy, SciPy, click, PyYAML, tqdm, cloudpickle, toolz, fsspec, msgpack, psutil, ...):
# the project's dependencies, for the step `distributed` dask's, and pytest-timeout (the
# suite's guard against a hung test: pyproject.toml).
names="pyopencl pytools platformdirs siphash24 trimesh embreex zarr numcodecs donfig
google-crc32c OpenEXR xatlas pydantic pydantic-core annotated-types typing-inspection
dask distributed tornado tblib zict partd locket pytest-timeout"
# name==version as this environment has them (importlib.metadata normalises the names)
pins=$("$py" -c '
import sys
from importlib.metadata import PackageNotFoundError, version
for name in sys.argv[1:]:
    try:
        print(f"{name}=={version(name)}")
    except PackageNotFoundError:
        sys.exit(f"device_prepare: {name} is not installed in {sys.executable}")
' $names)
rm -rf .whl && mkdir .whl
for pin in $pins; do
    "$py" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
        --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform manylinux1_x86_64 --platform any -d .whl "$pin" 2>&1 \
        | grep -v "^WARNING: Location" >&2 || true
done
count=$(ls .whl | wc -l)
[ "$count" -eq "$(echo $pins | wc -w)" ] || { echo "device_prepare: $count wheels for $(echo $pins | wc -w) packages" >&2; exit 1; }
# The shared data: the maps and meshes that a file of the project names (a 64 MiB carry
# has no room for the others), every other file and folder as it is.
data=${PRT_DATA:-../shared/data}
rm -rf .devdata && mkdir .devdata
for path in "$data"/*; do
    name=$(basename "$path")
    if [ "$name" != envmaps ] && [ "$name" != meshes ]; then
        cp -r "$path" .devdata/
        continue
    fi
    mkdir -p ".devdata/$name"
    for file in "$path"/*; do
        if git grep -qF "$(basename "$file")" -- ':!benchmarks/results'; then
            cp "$file" ".devdata/$name/"
        fi
    done
done
du -sh .whl .devdata
