"""Small infrastructure every layer may use, importing nothing above it: stop signals, exceptions, optional extras,
whole output files, progress lines, argument checks, entry points and renamed import names."""
