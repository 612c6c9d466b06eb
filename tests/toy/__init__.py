"""Small stages used only by tests of the runner (declared in tests/toy/stages.yaml)."""
