"""The simulator: the paper's manoeuvres, truth physics, sensors and CAN encoding."""
