"""ns2codegen: Neural-Swarm2 deep sets from PyTorch to the Crazyflie STM32."""
__version__ = "0.1.0"
