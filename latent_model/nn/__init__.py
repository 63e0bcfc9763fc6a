"""Networks of LatentReRig: SDF set encoder, SDF decoder, heads, vertex decoder, losses."""
