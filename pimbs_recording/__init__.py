"""The recording format (docs/recording-format.md): read, validate and write the Parquet
recordings that collection, simulation and import produce and learning reads, with crash-safe
atomic writes. One place both sides import; imports no other PIMBS room."""
