"""The bake engine: the stage file and its graph (stagefile, graph), chunks and their
keys (chunk, chunking, keys, codeversion), running them (runner, executors, stage: the
contract with a stage module), writing and reading artifacts (store, chunkwrite, rows,
schema, tolerance) and checking them (verify, inspect). It names no method."""
