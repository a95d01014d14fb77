"""The scene parameter table: every key declared once, with its type, unit, default and valid range.

The core rows are here; each registered method (a solver or boundary, ``warp_sph.methods``) adds the
rows of its own section (``pbf.max_iterations``, ...); a row is a ``Param`` (``param.py``).
``all_parameters()`` is the whole table in the order the scene-file reference (docs/scene-files.md)
shows it. That table drives validation, defaults, ``--set`` overrides, the typed section classes
(``warp_sph.scene.types``) and the generated docs (``warp_sph.docs``, ``parameter_table_markdown``).

Key paths: ``particle_radius`` (top level), ``material.rest_density`` (a table), ``fluid[0].max``
(an element of an array of tables; in the table written ``fluid[].max``).
"""
from __future__ import annotations

from dataclasses import replace

from ..core.smoothing import SMOOTHING_KERNELS
# the rows' type; Param, REQUIRED and TABLE_KINDS are imported from here too (validate.py, types.py, the methods)
from .param import KIND_NAMES, REQUIRED, TABLE_KINDS, Param, default_text, valid_text  # noqa: F401

MESH_SEQUENCE_FORMATS = ("", "obj", "ply", "vtk")
PARTICLE_PRIMVARS = ("density", "pressure")
FLUID_SHAPES = ("box", "sphere", "mesh")
OBSTACLE_SHAPES = ("box", "sphere", "mesh")
BODY_SHAPES = ("box", "sphere", "mesh")
PROBE_KINDS = ("pressure", "height", "front")
EMITTER_SHAPES = ("circle", "rectangle")
#: faces of the container that ``container.open`` may name: sign and axis
OPEN_FACES = ("-x", "+x", "-y", "+y", "-z", "+z")


_P = Param

#: Rows before the method sections.
_HEAD = (
    _P("name", "str", "-", "", "scene name (default: the file name without .toml); files of the run are named "
       "after it, with characters other than letters, digits, '-' and '_' replaced by '_'"),
    _P("description", "str", "-", "", "one-line description"),
    _P("particle_radius", "float", "m", 0.025, "particle radius r; the lattice spacing is d = 2r (at most 1 km: "
       "the kernel's float32 values underflow far above)", gt=0.0, le=1e3),
    _P("smoothing_kernel", "str", "-", "cubic", "smoothing kernel W (Liu & Liu 2010)",
       choices=tuple(SMOOTHING_KERNELS)),
    _P("h_per_spacing", "float", "-", None, "smoothing length h / d (absent: the kernel's default: "
       "1 for cubic and quadric, 2/3 for quintic, i.e. support 2d)", gt=0.0, le=4.0, default_text="kernel default"),
)
_AFTER_METHODS = (
    _P("boundary_gap", "float", "-", None, "initial distance from the boundary particles to the nearest fluid "
       "particle centres, in spacings d (absent: the gap at which the first layer next to one Akinci wall "
       "layer is at rest density, physics notes section 7: cubic 1.10, quadric 1.08, quintic 1.03)",
       ge=0.5, le=3.0, default_text="auto"),
    _P("gravity", "vec3", "m/s^2", (0.0, 0.0, -9.81), "gravitational acceleration (Z is up); its length at most "
       "1000 m/s^2 (about 100 g)", le=1e3),
    _P("duration", "float", "s", 2.0, "simulated time", gt=0.0),
    _P("fps", "float", "1/s", 24.0, "output frames per second of simulated time", gt=0.0),
    # material
    _P("material", "table", "-", {}, "fluid material"),
    _P("material.rest_density", "float", "kg/m^3", 1000.0, "rest density rho0 (water 1000; 1e-3..1e5 covers "
       "every liquid and keeps float32 sums exact)", ge=1e-3, le=1e5),
    _P("material.viscosity", "float", "m^2/s", 0.0, "kinematic viscosity, explicit (SPlisHSPlasH "
       "'standard' form); needs dt <= 0.0625 (H_s/2)^2 / nu; sets [[forces]] method = \"explicit_viscosity\" "
       "(docs/forces.md)", ge=0.0),
    _P("material.xsph", "float", "-", 0.0, "XSPH velocity smoothing factor (report eq. 21); sets [[forces]] "
       "method = \"xsph\"", ge=0.0, le=1.0),
    _P("material.boundary_friction", "float", "-", 0.0, "Akinci boundary friction sigma (report eq. 22-24); "
       "explicit: needs dt <= 0.0625 (H_s/2)^2 / nu_b with nu_b = sigma h c_s / (2 rho0)", ge=0.0),
)
#: Rows after the method sections.
_TAIL = (
    # time
    _P("time", "table", "-", {}, "time stepping"),
    _P("time.cfl", "float", "-", 0.4, "CFL number lambda of the adaptive step", gt=0.0, le=1.0),
    _P("time.dt_min", "float", "s", 1e-6, "smallest adaptive step", gt=0.0),
    _P("time.dt_max", "float", "s", 5e-3, "largest adaptive step", gt=0.0),
    _P("time.fixed_dt", "float", "s", 0.0, "fixed step (0: adaptive)", ge=0.0),
    _P("time.on_instability", "str", "-", "stop", "when the watchdog finds a non-finite value or an "
       "escaped particle: 'stop' with an error (frames so far are kept) or 'retry' the frame with "
       "half the time step", choices=("stop", "retry")),
    _P("time.max_steps", "int", "-", 10_000_000, "refuse a run that would take more substeps than this "
       "(estimated before the first step from the time-step bounds at the scene's reference speed)", ge=1),
    _P("time.settle", "float", "m/s", 0.0, "packing pass before t = 0 (docs/validation-notes.md): the solver steps the "
       "fluid with its velocity damped by 10 % a step until the fluid's mean speed, averaged over a frame "
       "(1/fps) of packing, is below this; then the run starts there at rest (0: off, the fluid starts on its "
       "lattice)", ge=0.0),
    _P("time.settle_steps", "int", "-", 3000, "most steps of the packing pass (time.settle); when reached the run "
       "starts anyway and run.json's settle.converged is false", ge=1),
    # container
    _P("container", "table_or_false", "-", {}, "box of boundary-particle walls (six faces); "
       "'container = false': no walls", default_text="box"),
    _P("container.min", "vec3", "m", (0.0, 0.0, 0.0), "lower corner of the container"),
    _P("container.max", "vec3", "m", (4.0, 1.5, 3.0), "upper corner of the container"),
    _P("container.open", "str_list", "-", (), "open faces, an outflow (docs/emitters.md): no wall particles on "
       "them, and fluid past one is removed at the next frame's start as by a sink (an open top, the face "
       "gravity points away from: only fluid over its rim, past a side wall's plane); '+x' is the face at "
       "container.max[0], '-x' the one at container.min[0]", choices=OPEN_FACES),
    _P("container.inner", "bool", "-", False, "true: min/max are the tank's inner faces, the water's boundary "
       "(an experiment's tank): the wall particles stand the water offset g d - r (about 0.6 d) outside them, so "
       "water given flush with a wall fills the box at every resolution, and a probe on a face of the box moves "
       "with its wall (docs/validation-notes.md); false: min/max are the wall particles' planes"),
    # fluid blocks
    _P("fluid", "tables", "-", REQUIRED, "fluid blocks ([[fluid]]), at least one"),
    _P("fluid[].shape", "str", "-", "box", "block shape", choices=FLUID_SHAPES),
    _P("fluid[].min", "vec3", "m", REQUIRED, "lower corner of a box block", shapes=("box",)),
    _P("fluid[].max", "vec3", "m", REQUIRED, "upper corner of a box block", shapes=("box",)),
    _P("fluid[].center", "vec3", "m", REQUIRED, "centre of a sphere block", shapes=("sphere",)),
    _P("fluid[].radius", "float", "m", REQUIRED, "radius of a sphere block", gt=0.0, shapes=("sphere",)),
    _P("fluid[].file", "str", "-", REQUIRED, "closed triangle mesh whose inside is filled (.obj .stl .ply .usd "
       ".usda .usdc); relative to the scene file, else one shipped in scenes/meshes/", shapes=("mesh",)),
    _P("fluid[].scale", "float", "-", 1.0, "uniform scale of the mesh (x -> scale x + translate)",
       gt=0.0, shapes=("mesh",)),
    _P("fluid[].translate", "vec3", "m", (0.0, 0.0, 0.0), "translation of the mesh", shapes=("mesh",)),
    _P("fluid[].velocity", "vec3", "m/s", (0.0, 0.0, 0.0), "initial velocity"),
    _P("fluid[].spacing_scale", "float", "-", 1.0, "lattice spacing / d; < 1 starts the block "
       "over-dense (compressed)", ge=0.5, le=2.0),
    _P("fluid[].lattice", "str", "-", "cubic", "the start's lattice: cubic (spacing d); fcc, face-centred cubic with "
       "nearest neighbours d (the points of a cubic grid of spacing d/sqrt(2) whose indices sum to an even number: "
       "every face a square net of spacing d, each particle over four of the layer below), 1.41x the particles, "
       "mass and wall gap calibrated on it; a stable rest state under pressure where the cubic lattice's columns "
       "slip (issue #31, docs/validation-notes.md); one lattice for every block, cubic with emitters",
       choices=("cubic", "fcc")),
    _P("fluid[].jitter", "float", "-", 0.0, "seeded perturbation of the start, a fraction of d: each coordinate of "
       "each particle of the block moves by a uniform draw in [-jitter d, +jitter d] (an ensemble of runs of a "
       "chaotic flow, docs/validation.md); 0: the lattice as it is", ge=0.0, lt=1.0),
    _P("fluid[].seed", "int", "-", 0, "seed of fluid[].jitter's draws (the same seed, the same start bit for bit)",
       ge=0),
    # obstacles
    _P("obstacles", "tables", "-", [], "static obstacles ([[obstacles]]), sampled as boundary particles",
       default_text="none"),
    _P("obstacles[].shape", "str", "-", "box", "obstacle shape", choices=OBSTACLE_SHAPES),
    _P("obstacles[].min", "vec3", "m", REQUIRED, "lower corner of a box obstacle", shapes=("box",)),
    _P("obstacles[].max", "vec3", "m", REQUIRED, "upper corner of a box obstacle", shapes=("box",)),
    _P("obstacles[].center", "vec3", "m", REQUIRED, "centre of a sphere obstacle (an animated one: in its local "
       "frame, the path moves it)", shapes=("sphere",)),
    _P("obstacles[].radius", "float", "m", REQUIRED, "radius of a sphere obstacle", gt=0.0, shapes=("sphere",)),
    _P("obstacles[].file", "str", "-", REQUIRED, "closed triangle mesh (.obj .stl .ply .usd .usda .usdc); "
       "relative to the scene file", shapes=("mesh",)),
    _P("obstacles[].scale", "float", "-", 1.0, "uniform scale of the mesh (x -> scale x + translate)",
       gt=0.0, shapes=("mesh",)),
    _P("obstacles[].translate", "vec3", "m", (0.0, 0.0, 0.0), "translation of the mesh", shapes=("mesh",)),
    # animated colliders (warp_sph/scene/paths.py, warp_sph/run/colliders.py, docs/colliders.md)
    _P("obstacles[].name", "str", "-", "", "name of an animated obstacle in the USD file and run.json (default: "
       "obstacle<index>); letters, digits and '_', not starting with a digit"),
    _P("obstacles[].interpolation", "str", "-", "smooth", "how an animated obstacle moves between its keys: "
       "'linear' (velocity jumps at keys) or 'smooth' (cubic Hermite, Catmull-Rom tangents, at rest at the "
       "first and last key)", choices=("linear", "smooth")),
    _P("obstacles[].keyframes", "tables", "-", [], "keys of an animated obstacle's path (keyframes = [{time = 0.0, "
       "translate = [...], rotation = [...]}, ...]): x = R(t) x_local + T(t), x_local the geometry as written; the "
       "end poses are held before the first and after the last key", default_text="none"),
    _P("obstacles[].keyframes[].time", "float", "s", REQUIRED, "time of the key (strictly increasing)"),
    _P("obstacles[].keyframes[].translate", "vec3", "m", (0.0, 0.0, 0.0), "translation T of the local origin"),
    _P("obstacles[].keyframes[].rotation", "vec3", "deg", (0.0, 0.0, 0.0), "rotation about the local origin as "
       "Euler angles about X, then Y, then Z (Blender's XYZ mode); each angle is interpolated on its own, so "
       "0 -> 360 is a full turn"),
    _P("obstacles[].animation", "table", "-", {}, "the obstacle's path from a transform animated in a USD file "
       "(animation = {file = \"paddle.usda\", prim = \"/paddle\"}; Blender's USD export), instead of keyframes",
       default_text="none"),
    _P("obstacles[].animation.file", "str", "-", REQUIRED, "USD file (.usd .usda .usdc), relative to the scene file"),
    _P("obstacles[].animation.prim", "str", "-", REQUIRED, "absolute path of the animated prim, e.g. '/paddle'; its "
       "local-to-world transform at each time sample, t = (time code - startTimeCode) / timeCodesPerSecond"),
    # moving rigid bodies (warp_sph.rigid): Akinci 2012 two-way coupling, dynamics by Newton
    _P("bodies", "tables", "-", [], "moving rigid bodies ([[bodies]]), two-way coupled with the fluid "
       "(Akinci et al. 2012) and stepped by Newton (the rigid extra)", default_text="none"),
    _P("bodies[].name", "str", "-", "", "name of the body in the USD file and run.json (default: body<index>); "
       "letters, digits and '_', not starting with a digit"),
    _P("bodies[].shape", "str", "-", "box", "body shape", choices=BODY_SHAPES),
    _P("bodies[].size", "vec3", "m", REQUIRED, "edge lengths of a box body", shapes=("box",)),
    _P("bodies[].radius", "float", "m", REQUIRED, "radius of a sphere body", gt=0.0, shapes=("sphere",)),
    _P("bodies[].file", "str", "-", REQUIRED, "closed triangle mesh (.obj .stl .ply .usd .usda .usdc), relative to "
       "the scene file; it collides as its convex hull and couples to the fluid with its true surface",
       shapes=("mesh",)),
    _P("bodies[].scale", "float", "-", 1.0, "uniform scale of the mesh", gt=0.0, shapes=("mesh",)),
    _P("bodies[].position", "vec3", "m", REQUIRED, "initial position of the centre of mass (not with "
       "kinematic = true)"),
    _P("bodies[].rotation", "vec3", "deg", (0.0, 0.0, 0.0), "initial orientation as Euler angles about X, "
       "then Y, then Z (Blender's XYZ rotation mode)"),
    _P("bodies[].density", "float", "kg/m^3", None, "density (give density or mass, not both)", gt=0.0, le=1e6,
       default_text="density or mass"),
    _P("bodies[].mass", "float", "kg", None, "mass (give density or mass, not both)", gt=0.0,
       default_text="density or mass"),
    _P("bodies[].velocity", "vec3", "m/s", (0.0, 0.0, 0.0), "initial velocity of the centre of mass"),
    _P("bodies[].angular_velocity", "vec3", "rad/s", (0.0, 0.0, 0.0), "initial angular velocity (world axes)"),
    # kinematic bodies (docs/colliders.md): turned into animated obstacles at validation (scene/kinematic.py)
    _P("bodies[].kinematic", "bool", "-", False, "the body follows a path (keyframes or animation) instead of "
       "Newton's dynamics: an animated collider that pushes the fluid and is not pushed back; keys give its pose "
       "outright (position, rotation, density, mass, velocity, angular_velocity and fluid_friction are refused); "
       "box and mesh shapes"),
    _P("bodies[].interpolation", "str", "-", None, "how a kinematic body moves between its keys (as "
       "obstacles[].interpolation)", choices=("linear", "smooth"), default_text="\"smooth\""),
    _P("bodies[].keyframes", "tables", "-", [], "keys of a kinematic body's path, as obstacles[].keyframes: "
       "translate = the centre of mass [m], rotation = the orientation [deg] (Euler XYZ)", default_text="none"),
    _P("bodies[].animation", "table", "-", {}, "a kinematic body's path from a transform animated in a USD file, "
       "as obstacles[].animation (the prim's transform is the pose of the body's frame)", default_text="none"),
    _P("bodies[].fluid_friction", "float", "-", None, "Akinci boundary friction sigma between this body and "
       "the fluid (absent: material.boundary_friction)", ge=0.0, default_text="material.boundary_friction"),
    # probes (warp_sph.run.probes): sampled during the run, one CSV per probe in the run folder
    _P("probes", "tables", "-", [], "probes ([[probes]]): wall pressure, water height or surge front sampled "
       "during the run into probe_<name>.csv (docs/probes.md)", default_text="none"),
    _P("probes[].name", "str", "-", "", "name of the probe in its CSV file and run.json (default: probe<index>); "
       "letters, digits, '-' and '_'"),
    _P("probes[].kind", "str", "-", REQUIRED, "'pressure': Shepard-weighted fluid pressure at a point on or near a "
       "wall [Pa]; 'height': free-surface elevation along a vertical line [m]; 'front': the furthest fluid along a "
       "line [m]", choices=PROBE_KINDS),
    _P("probes[].position", "vec3", "m", REQUIRED, "the pressure point, or the start of the height or front line"),
    _P("probes[].axis", "vec3", "-", (1.0, 0.0, 0.0), "direction of a front line (normalised)", shapes=("front",)),
    _P("probes[].length", "float", "m", None, "length of a height or front line (absent: up to the container wall)",
       gt=0.0, shapes=("height", "front"), default_text="to the wall"),
    _P("probes[].sensor_diameter", "float", "m", 0.0, "a pressure probe on a container wall as a transducer of "
       "this face diameter: the fluid's normal force on the wall particles under the face per unit area, averaged "
       "over each sample interval (0: the wall load spread with the 2D kernel of the support radius)", ge=0.0,
       shapes=("pressure",)),
    _P("probes[].rate", "float", "Hz", 100.0, "samples per second of simulated time; at most one per substep",
       gt=0.0),
    _P("probes[].experiment", "str", "-", "", "a shipped measured series (warp_sph/validation/data, with its "
       "citation) that 'warp-sph plot' draws beside this probe, in SI units (docs/validation.md); '': none",
       choices=("", "lobovsky_2014_sensor1", "lobovsky_2014_sensor3", "lobovsky_2014_sensor4")),
    # emitters and sinks (warp_sph.run.emission): a changing particle count (docs/emitters.md)
    _P("max_particles", "int", "-", 0, "fluid particle capacity, allocated once (0: the initial fluid plus "
       "every emitter's volume over its active time, plus 5 %); emission stops with one warning when it is "
       "full", ge=0, default_text="auto"),
    _P("emitters", "tables", "-", [], "emitters ([[emitters]]): fluid entering in lattice layers through a "
       "nozzle (docs/emitters.md)", default_text="none"),
    _P("emitters[].shape", "str", "-", "circle", "nozzle shape: a disc or a rectangle, normal to direction",
       choices=EMITTER_SHAPES),
    _P("emitters[].position", "vec3", "m", REQUIRED, "centre of the nozzle"),
    _P("emitters[].direction", "vec3", "-", REQUIRED, "direction of the flow (normalised)"),
    _P("emitters[].radius", "float", "m", REQUIRED, "radius of a circle nozzle", gt=0.0, shapes=("circle",)),
    _P("emitters[].width", "float", "m", REQUIRED, "width of a rectangle nozzle: horizontal, along z x direction (along y "
       "for a vertical direction)",
       gt=0.0, shapes=("rectangle",)),
    _P("emitters[].height", "float", "m", REQUIRED, "height of a rectangle nozzle", gt=0.0, shapes=("rectangle",)),
    _P("emitters[].speed", "float", "m/s", None, "speed of the entering fluid (give speed or flow_rate)", gt=0.0),
    _P("emitters[].flow_rate", "float", "m^3/s", None, "volume per second (give speed or flow_rate; the speed is "
       "the rate over the nozzle's lattice area)", gt=0.0),
    _P("emitters[].start", "float", "s", 0.0, "time the emission starts", ge=0.0),
    _P("emitters[].end", "float", "s", None, "time the emission ends (absent: the scene's duration)", ge=0.0,
       default_text="duration"),
    _P("sinks", "tables", "-", [], "sinks ([[sinks]]): boxes that remove the fluid entering them, checked at "
       "every frame (docs/emitters.md)", default_text="none"),
    _P("sinks[].min", "vec3", "m", REQUIRED, "lower corner of the sink box"),
    _P("sinks[].max", "vec3", "m", REQUIRED, "upper corner of the sink box"),
    _P("rigid", "table", "-", {}, "contacts of the rigid bodies (Newton, penalty contacts)"),
    _P("rigid.contact_friction", "float", "-", 0.5, "Coulomb friction coefficient of every body contact "
       "(body-body, body-wall, body-obstacle)", ge=0.0, le=10.0),
    _P("rigid.contact_frequency", "float", "rad/s", 0.0, "contact stiffness as the angular frequency w of a "
       "body pair on its contact spring (0: sqrt(g / (0.01 r)) with g the magnitude of gravity: a resting body sinks "
       "in by 1 % of r); "
       "Newton steps are at most 1 / (4 w)", ge=0.0, le=1e5, default_text="auto"),
    # whitewater (warp_sph/run/whitewater.py, docs/whitewater.md): Ihmsen et al. 2012 secondary particles;
    # defaults are SPlisHSPlasH's FoamGenerator's (r = 0.025 m), off unless the scene has [whitewater]
    _P("whitewater", "table", "-", None, "spray, foam and air bubbles (Ihmsen et al. 2012) generated from the fluid "
       "and written to /sph/whitewater (docs/whitewater.md); off unless the scene has this table",
       default_text="off"),
    _P("whitewater.enabled", "bool", "-", True, "generate and advect whitewater (false: as if the table were absent)"),
    _P("whitewater.seed", "int", "-", 0, "seed of the sampling (runs and resumes are reproducible bit for bit)",
       ge=0, le=2**31 - 1),
    _P("whitewater.max_particles", "int", "-", 200_000, "capacity, allocated once; particles generated when it "
       "is full are dropped (one warning)", ge=1, le=100_000_000),
    _P("whitewater.trapped_air_min", "float", "m/s", 5.0, "trapped-air potential (sum of weighted relative "
       "speeds of approaching neighbours) mapped to 0 at and below this", ge=0.0),
    _P("whitewater.trapped_air_max", "float", "m/s", 20.0, "trapped-air potential mapped to 1 at and above this "
       "(> trapped_air_min)", gt=0.0),
    _P("whitewater.wave_crest_min", "float", "-", 2.0, "wave-crest potential (weighted normal curvature of a "
       "convex surface moving along its normal) mapped to 0 at and below this", ge=0.0),
    _P("whitewater.wave_crest_max", "float", "-", 8.0, "wave-crest potential mapped to 1 at and above this "
       "(> wave_crest_min)", gt=0.0),
    _P("whitewater.kinetic_energy_min", "float", "J/kg", 5.0, "kinetic energy per mass v^2/2 mapped to 0 at and "
       "below this (no generation from slower particles)", ge=0.0),
    _P("whitewater.kinetic_energy_max", "float", "J/kg", 50.0, "kinetic energy per mass mapped to 1 at and above "
       "this (> kinetic_energy_min)", gt=0.0),
    _P("whitewater.trapped_air_rate", "float", "1/s", 500.0, "k_ta: particles generated per fluid particle and "
       "second at full trapped-air and kinetic-energy potentials", ge=0.0),
    _P("whitewater.wave_crest_rate", "float", "1/s", 6250.0, "k_wc: particles generated per fluid particle and "
       "second at full wave-crest and kinetic-energy potentials", ge=0.0),
    _P("whitewater.lifetime_min", "float", "s", 2.0, "shortest lifetime of a foam particle (drawn uniformly in "
       "[lifetime_min, lifetime_max] at birth; it ages only while it is foam)", gt=0.0),
    _P("whitewater.lifetime_max", "float", "s", 5.0, "longest lifetime of a foam particle (>= lifetime_min)",
       gt=0.0),
    _P("whitewater.buoyancy", "float", "-", 2.0, "k_b: an air bubble accelerates by -k_b g (upwards)", ge=0.0),
    _P("whitewater.drag", "float", "-", 0.8, "k_d: the fraction of its velocity difference to the fluid a bubble "
       "loses per step", ge=0.0, le=1.0),
    _P("whitewater.spray_neighbors", "int", "-", 6, "a particle with fewer fluid neighbours than this within the "
       "kernel support is spray", ge=1),
    _P("whitewater.bubble_neighbors", "int", "-", 20, "a particle with more fluid neighbours than this is an air "
       "bubble; between the two it is foam (>= spray_neighbors)", ge=1),
    _P("whitewater.fluid_sampling", "str", "-", "walk", "how a secondary particle reads the fluid's kernel-averaged "
       "velocity and neighbour count: walk (each particle walks its fluid neighbours: exact) or grid (trilinear "
       "from nodes H/2 apart, evaluated once per step near the particles: cheaper with many particles per node, "
       "about 10,000 or more on the dam break)",
       choices=("grid", "walk")),
    _P("whitewater.point_width", "float", "-", 0.5, "width of the written points / r", gt=0.0, le=10.0),
    # output. Surface (warp_sph/surface/reconstruction.py): Phi = sum_j f_j / rho~_j with
    # f = (1 - r^2/R^2)^5 and rho~ from the same f (mass, rest density and walls cancel, Phi ~ 1 in
    # the bulk); on a rest lattice the 0.6 level lies 1.0 r beyond the last particle layer (ripple
    # 0.007 r), splashsurf's default level. Cells of 0.5 r are splashsurf's usual cube size; the
    # cost grows with the surface area / cell^2 (sparse narrow band). Defaults (cells of 2 r, 5
    # smoothing steps, no decimation): the default dam break's surface in ~1/10 of the CPU time of
    # 1.0 r with 15 steps and decimation to convergence, as many triangles, flatter pool and rounder
    # sphere (docs/performance.md); more steps on coarse cells grow marching cubes' "barnacles".
    _P("output", "table", "-", {}, "what a run writes"),
    _P("output.usd", "bool", "-", True, "write a USD stage (points, and the surface mesh if surface)"),
    _P("output.surface", "bool", "-", True, "reconstruct the fluid surface (marching cubes)"),
    _P("output.surface_cell_per_radius", "float", "-", 2.0, "surface grid cell size / r (2.0: with 5 "
       "smoothing steps flatter and rounder than 1.0 with 15 steps and decimation, as many triangles, "
       "about 1/10 of the cost; docs/performance.md)", ge=0.1, le=4.0),
    _P("output.surface_method", "str", "-", "marching_cubes", "iso-surface extraction: marching cubes "
       "on the sparse narrow band (Warp's case table)", choices=("marching_cubes",)),
    _P("output.surface_iso", "float", "-", 0.6, "iso level of Phi = sum_j f_j/rho~_j (1 inside the "
       "fluid; 0.6 lies 1.0 r beyond the last particle layer, splashsurf's default)", gt=0.0, lt=1.0),
    _P("output.surface_spray_neighbors", "int", "-", 5, "particles with fewer fluid neighbours than "
       "this within the kernel support are spray: written as points to /sph/spray, left out of the "
       "surface (0: no spray); at most the neighbours of a particle on a flat free surface (17 at the "
       "default support 2d), above which the whole surface would be spray", ge=0),
    _P("output.surface_smoothing_iterations", "int", "-", 5, "feature-weighted Laplacian smoothing "
       "steps of the surface, volume restored after them (removes the particle-scale ridges, keeps "
       "droplets and thin sheets; 0: raw marching cubes)", ge=0, le=1000),
    _P("output.surface_decimation_error", "float", "-", 0.0, "decimate the smoothed surface by edge "
       "collapses (quadric error) that keep each merged vertex within this distance of the planes of "
       "all the faces it replaces, in particle radii (0: no decimation; 0.5 with the default rounds "
       "removes ~14 % of the triangles per round)", ge=0.0),
    _P("output.surface_decimation_rounds", "int", "-", 0, "most rounds of parallel edge collapses per "
       "frame (each rebuilds the connectivity; 0: 2 rounds, or up to 40 while a triangle budget is unmet)",
       ge=0, le=1000, default_text="auto"),
    _P("output.surface_triangle_budget", "int", "-", 0, "decimate until the surface has at most this "
       "many triangles per frame, within the error bound if one is set (0: no budget)", ge=0),
    _P("output.surface_normal_smoothing_iterations", "int", "-", 10, "one-ring averaging steps of "
       "the surface's vertex normals", ge=0, le=1000),
    _P("output.surface_normals", "bool", "-", True, "write vertex normals (primvars:normals: smooth "
       "shading in Blender without modifiers)"),
    _P("output.mesh_sequence", "str", "-", "", "also write one surface mesh file per frame "
       "('' for none; needs output.surface = true)", choices=MESH_SEQUENCE_FORMATS),
    _P("output.particle_primvars", "str_list", "-", ("density",), "per-particle fields written to USD",
       choices=PARTICLE_PRIMVARS),
    _P("output.checkpoint_every", "int", "-", 10, "write a checkpoint every this many frames "
       "(0: never)", ge=0),
    _P("output.record_frames", "bool", "-", True, "record per-frame diagnostics in run.json"),
    # the prediction of ``warp-sph plan --apply`` (docs/plan.md): a run compares it with what happened (run.json "plan")
    _P("plan", "table", "-", None, "the prediction of warp-sph plan, written by --apply; the run records it "
       "beside what happened (run.json plan)", default_text="none"),
    _P("plan.wall_time", "float", "s", 0.0, "predicted wall time of the run", ge=0.0),
    _P("plan.density_error", "float", "-", 0.0, "predicted mean density error", ge=0.0),
    _P("plan.steps", "int", "-", 0, "predicted substeps", ge=0),
    _P("plan.fluid_particles", "int", "-", 0, "predicted fluid particles", ge=0),
    _P("plan.memory", "float", "B", 0.0, "predicted memory", ge=0.0),
    _P("plan.budget", "float", "s", 0.0, "the wall-time budget asked for (0: none)", ge=0.0),
    _P("plan.target_error", "float", "-", 0.0, "the mean density error asked for (0: none)", ge=0.0),
    _P("plan.metric", "str", "-", "density", "the error the plan targeted: 'density' or a validation scene's "
       "error against its experiment ('front', 'sensor1', ...; docs/plan.md)"),
    _P("plan.metric_error", "float", "-", 0.0, "predicted error of plan.metric against the experiment (0: the "
       "density error)", ge=0.0),
)


def _method_rows() -> tuple[Param, ...]:
    """The ``solver`` and ``boundary`` rows (choices from the registry) and every method's section."""
    from ..methods import registry

    solvers = registry.solvers()
    boundaries = registry.boundaries()
    rows = [
        _P("solver", "str", "-", registry.DEFAULT_SOLVER, "pressure solver: " + "; ".join(
            f"{name}: {cls.title}" for name, cls in solvers.items()), choices=tuple(solvers)),
        _P("boundary", "str", "-", registry.DEFAULT_BOUNDARY, "boundary handling: " + "; ".join(
            f"{name}: {cls.title}" for name, cls in boundaries.items()), choices=tuple(boundaries)),
    ]
    for name, cls in list(solvers.items()) + list(boundaries.items()):
        if cls.parameters:
            rows.append(_P(name, "table", "-", {}, cls.section_doc or f"{cls.title} settings"))
            rows.extend(cls.parameters)
    return tuple(rows) + _force_rows(registry.forces())


def _force_rows(forces: dict) -> tuple[Param, ...]:
    """``[[forces]]``: the array, its ``method`` and each force's keys as ``forces[<method>].<key>``."""
    rows = [
        _P("forces", "tables", "-", [], "non-pressure forces ([[forces]], docs/forces.md), at most one of each kind: "
           + "; ".join(f"{name} ({cls.kind.replace('_', ' ')}): {cls.title}" for name, cls in forces.items()),
           default_text="none"),
        _P("forces[].method", "str", "-", REQUIRED, "the force method; its keys are the rows forces[<method>].<key>",
           choices=tuple(forces)),
    ]
    for name, cls in forces.items():
        rows.extend(replace(p, path=f"forces[{name}].{p.key}") for p in cls.parameters)
    return tuple(rows)


def parameter(path: str) -> Param:
    """The row of key path ``path`` (``output.surface_cell_per_radius``, ``fluid[].max``); KeyError if none."""
    for p in all_parameters():
        if p.path == path:
            return p
    raise KeyError(path)


def all_parameters() -> tuple[Param, ...]:
    """Every scene parameter, core and registered methods, in table order."""
    return _HEAD + _method_rows() + _AFTER_METHODS + _TAIL


def core_parameters() -> tuple[Param, ...]:
    """The rows that do not belong to a method's section."""
    return _HEAD + _AFTER_METHODS + _TAIL


def by_section(params: tuple[Param, ...]) -> dict[str, dict[str, Param]]:
    """{section: {key: Param}} ("" for the top level)."""
    out: dict[str, dict[str, Param]] = {}
    for p in params:
        out.setdefault(p.section, {})[p.key] = p
    return out


def parameter_table_markdown() -> str:
    """The scene parameters as a Markdown table: key, type, unit, default, valid values, meaning."""
    lines = ["| key | type | unit | default | valid | description |", "|---|---|---|---|---|---|"]
    for p in all_parameters():
        doc = p.doc.replace("|", "\\|")
        lines.append(f"| `{p.path}` | {KIND_NAMES[p.kind]} | {p.unit} | {default_text(p)} | {valid_text(p, vec3_length=True)} "
                     f"| {doc} |")
    return "\n".join(lines) + "\n"
