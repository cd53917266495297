"""`pimbs collect`: the body-schema data collection routine on a real or simulated arm.

plan (seeded poses and the tensions that hold them) -> settle (wait until the readings are
quiet) -> routine (the loop, one crash-safe row per sample) ; resume (continue a file) ;
estimate (θ without joint encoders) ; link (the narrow arm interface the routine needs).
"""
