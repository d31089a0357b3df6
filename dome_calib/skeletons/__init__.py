"""People out: body3DScene folders read through their schema, written for OpenSim and Pose2Sim (TRC), C3D tools
and animation tools (BVH), and shown on a self-contained page (``index.html``)."""
