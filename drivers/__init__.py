"""dishbot drivers: Dynamixel bus, FSR reader, cameras, device simulators and the simulated world."""
