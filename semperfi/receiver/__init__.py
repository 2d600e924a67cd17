"""The conventional receiver chain: acquisition, tracking, navigation, observables, PVT, outputs."""
