"""ns2paper: the reproduction of the paper's own flights, fenced apart from the product.

authors.py     the authors' published networks as a project model (`ns2 real import-authors`)
collection.py  the authors' three data collections (2019-12-11, 2019-12-20, 2020-06-16): their
               robots, scenarios and flights as flights.toml manifests
gains.py       the gains of the controller that flew the real flights (params/authors_gains.toml)
               and the z law read off them (params/read_law.toml, written by `make calibrate`)
controller.py  that controller in the simulator (AuthorsController: a position law of the
               kernel, its C in c/ctrl_authors.c)
flightstats.py the flight statistics measured alike on real and replayed flights
replay.py      a real flight's logged setpoints flown by the same team in the simulator

It imports the core, the host side and the simulator; no product package (ns2codegen,
ns2host, ns2host.sim, ns2plan, ns2ground, the CLI's product commands) imports it; the
experiments (ns2exp) and the CLI's experiment commands do (tests/test_layers.py).
"""
