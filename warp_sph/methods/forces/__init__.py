"""Non-pressure forces, one module per method (``warp_sph.methods.force``)."""
