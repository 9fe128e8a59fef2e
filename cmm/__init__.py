"""CMM measurement station: PIC-SERVO NMC driver, simulator, machine layer, metrology and browser UI."""

__version__ = "0.1.0"
