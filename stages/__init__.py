"""One module per DVC stage. Each reads its inputs and its own config section, calls the library,
and writes its artifacts; none imports another."""
