"""dishbot planning: placement planning (packing, costs, optimisers) and motion planning."""
