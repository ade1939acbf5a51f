"""Every ``rose:`` attribute name, defined once (``schemas/schema.usda`` declares them; a test
checks the two agree). Stage code names attributes only through these."""

# camera
CAMERA_K = "rose:camera:K"
CAMERA_INTRINSICS_SOURCE = "rose:camera:intrinsicsSource"
CAMERA_RESOLUTION = "rose:camera:resolution"

# collect
COLLECT_BASE_POSE = "rose:collect:basePose"
COLLECT_BASE_SOURCE = "rose:collect:baseSource"
COLLECT_BEST_ROLLOUT = "rose:collect:bestRollout"
COLLECT_DATASET = "rose:collect:dataset"
COLLECT_DRIFT = "rose:collect:drift"
COLLECT_FINAL_ERROR = "rose:collect:finalError"
COLLECT_FINAL_ROTATION_ERROR = "rose:collect:finalRotationError"
COLLECT_JOINT_NAMES = "rose:collect:jointNames"
COLLECT_JOINT_POSITIONS = "rose:collect:jointPositions"
COLLECT_MEAN_ERROR = "rose:collect:meanError"
COLLECT_MESSAGE = "rose:collect:message"
COLLECT_OBJECT = "rose:collect:object"
COLLECT_PENETRATION = "rose:collect:penetration"
COLLECT_ROLLOUTS = "rose:collect:rollouts"
COLLECT_ROLLOUT_GRASP = "rose:collect:rolloutGrasp"
COLLECT_ROLLOUT_REASON = "rose:collect:rolloutReason"
COLLECT_ROLLOUT_SUCCESS = "rose:collect:rolloutSuccess"
COLLECT_STATUS = "rose:collect:status"
COLLECT_SUCCESSES = "rose:collect:successes"
COLLECT_SUCCESS_RATE = "rose:collect:successRate"

# gate
GATE_GEOMETRY_PASSED = "rose:gate:geometry:passed"
GATE_GEOMETRY_REPORT = "rose:gate:geometry:report"
GATE_PASSED = "rose:gate:passed"
GATE_PHYSICS_DISPLACEMENT = "rose:gate:physics:displacement"
GATE_PHYSICS_DURATION = "rose:gate:physics:duration"
GATE_PHYSICS_OBJECTS = "rose:gate:physics:objects"
GATE_PHYSICS_PASSED = "rose:gate:physics:passed"
GATE_PHYSICS_ROTATION = "rose:gate:physics:rotation"
GATE_PHYSICS_THRESHOLD = "rose:gate:physics:threshold"
GATE_RENDER_VARIANT = "rose:gate:renderVariant"
GATE_SAMPLES_PER_PIXEL = "rose:gate:samplesPerPixel"
GATE_SSIM = "rose:gate:ssim"
GATE_SSIM_MEAN = "rose:gate:ssimMean"
GATE_SSIM_PASSED = "rose:gate:ssimPassed"
GATE_SSIM_THRESHOLD = "rose:gate:ssimThreshold"

# masks
MASKS_CONFIDENCE = "rose:masks:confidence"
MASKS_FILE = "rose:masks:file"
MASKS_OBJECT_NAME = "rose:masks:objectName"
MASKS_ROLE = "rose:masks:role"
MASKS_VISIBLE_PIXELS = "rose:masks:visiblePixels"

# prior
PRIOR_CATEGORY = "rose:prior:category"
PRIOR_DENSITY = "rose:prior:density"
PRIOR_DENSITY_RANGE = "rose:prior:densityRange"
PRIOR_FRICTION = "rose:prior:friction"
PRIOR_FRICTION_UNCERTAINTY = "rose:prior:frictionUncertainty"
PRIOR_HOLLOW = "rose:prior:hollow"
PRIOR_MASS_UNCERTAINTY = "rose:prior:massUncertainty"
PRIOR_RESTITUTION = "rose:prior:restitution"
PRIOR_RESTITUTION_UNCERTAINTY = "rose:prior:restitutionUncertainty"
PRIOR_SHELL_THICKNESS = "rose:prior:shellThickness"
PRIOR_SOURCE = "rose:prior:source"

# shape (objects fitted to silhouettes)
SHAPE_PRIMITIVE = "rose:shape:primitive"
SHAPE_PROXY = "rose:shape:proxy"
SHAPE_SILHOUETTE_IOU = "rose:shape:silhouetteIou"
SHAPE_SOURCE = "rose:shape:source"

# trajectory
TRAJECTORY_CONFIDENCE = "rose:trajectory:confidence"
TRAJECTORY_SOURCE = "rose:trajectory:source"

# world
WORLD_GRAVITY_SOURCE = "rose:world:gravitySource"
WORLD_GRAVITY_UNCERTAINTY_DEG = "rose:world:gravityUncertaintyDeg"
WORLD_DEPTH_SHIFT_PX = "rose:world:depthShiftPx"
WORLD_METRIC_DEPTH = "rose:world:metricDepth"
WORLD_SCALE_ALPHA = "rose:world:scaleAlpha"
WORLD_SCALE_BETA = "rose:world:scaleBeta"
WORLD_SCALE_RESIDUAL = "rose:world:scaleResidual"
WORLD_SCALE_CUES = "rose:world:scaleCues"
WORLD_SCALE_CUE_SIGMAS = "rose:world:scaleCueSigmas"
WORLD_SCALE_CUE_VALUES = "rose:world:scaleCueValues"
WORLD_SCALE_SOURCE = "rose:world:scaleSource"
WORLD_SCALE_UNCERTAINTY = "rose:world:scaleUncertainty"
WORLD_WORLD_FROM_INPUT = "rose:world:worldFromInput"

# support
SUPPORT_HEIGHTS = "rose:support:heights"
SUPPORT_OBJECTS = "rose:support:objects"
