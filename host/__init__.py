"""ns2host: host side of ns2codegen (cffi build of the firmware C, C-in-the-loop)."""
