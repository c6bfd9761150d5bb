"""Vehicle parameters of the simulator: those of ns2codegen.vehicle (one source for
the simulator, the controller's gains and the generated firmware header).  The gains of
the controller that flew the paper's real flights and the z law read off them are the
paper's (ns2paper.gains)."""
from ns2codegen.vehicle import G, STRONG, Vehicle, base_type, default_gains, vehicle

__all__ = ["G", "STRONG", "Vehicle", "base_type", "default_gains", "vehicle"]
