"""ns2codegen: Neural-Swarm2 deep sets from PyTorch to the Crazyflie STM32 (the core;
imports no other layer of the project).

config.py     robot types, vehicles, model dims, interaction volume (default.toml)
data/         data sets: the CSR format, analytic sets, labels from flight logs
model.py      the heterogeneous deep set with spectral normalization
train.py      training; checkpoint.py: checkpoints that carry their config
quantize.py   fixed-point formats and the overflow proof
reference.py  bit-exact Python references of the C inference
export.py     C headers (templates/), manifest and config of an export folder
queries.py    inference queries as the C API sees them
logs/         Crazyflie uSD logs and multi-robot alignment
sysid.py      system identification from load-cell data; vehicle.py: vehicle parameters
errors.py     Ns2Error, the base of every expected error; fileio.py: atomic output
"""
__version__ = "0.1.0"
