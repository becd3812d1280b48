"""The generated bad-input corpus (issue 10): damaged inputs made at test time."""
