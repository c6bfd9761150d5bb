"""Real-flight logs: the Crazyflie uSD-card deck's binary format and multi-robot alignment."""
