"""Pressure solvers, one module each (imported and registered by ``warp_sph.methods.registry``)."""
