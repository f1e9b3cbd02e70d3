"""dishbot statechart: the loading job's states, events and guards as data, and the async machine."""
