"""The probe session shared by the probes: options, patterns, statistics."""
