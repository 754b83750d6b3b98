"""One module per DVC stage. Each reads its inputs and its own config section, calls the library,
and writes its artifacts; none imports another.

Importing this package first caps every numerical library at AVX2 (``tactile6d.runtime.instruction_sets``), before
any of them is loaded, so that the stages write the same bits on machines with and without AVX-512.
"""

from tactile6d.runtime.instruction_sets import pin as _pin

_pin()
