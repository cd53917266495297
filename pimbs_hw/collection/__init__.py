"""`pimbs collect`: the body-schema data collection routine on a real or simulated arm.

plan (seeded poses and the tensions that hold them) -> move (ramps between them) -> settle
(wait until the readings are quiet) -> routine (the loop, one crash-safe row per sample);
resume (open or continue the file, metadata) ; estimate (θ without joint encoders) ;
link (the narrow arm interface the routine needs) ; session (connect, advice on stops) ;
progress (live panel and summary).
"""
