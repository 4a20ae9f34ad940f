"""What the tests and benchmarks validate the product on: hidden aerodynamic effects and instrument
faults written as effect overlays, a grammar of random effect shapes, and small matrices. The
diagnosis never reads these: they make the reference data it is judged on."""
