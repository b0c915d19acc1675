"""Small infrastructure every layer may use, importing nothing above it: stop signals, exceptions, optional extras,
whole output files, progress lines, argument checks, entry points, renamed import names, a command's start-up
(the garbage collector kept off its imports) and the machine a measurement ran on."""
