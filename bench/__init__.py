"""``dishbot bench …``: the benchmarks, one module each. The top layer: nothing imports it."""
