"""The same scenario in other FMI masters: SSP export, libcosim and the other hosts, the conformance matrix."""
