"""Speed machinery: exact samplers and process plumbing, kept apart from the physics.

Nothing here changes a result; each piece is tested to give the same values (or the
same distribution, exactly) as the plain numpy way, only faster:

* :mod:`noise.fast.normal`: vectorised Box-Muller normals with exact 53-bit tails;
* :mod:`noise.fast.poisson`: exact Poisson draws by inversion and guide tables;
* :mod:`noise.fast.seedhash`: numpy's ``SeedSequence`` hash, vectorised over many
  spawn keys (bit-identical generators, built together);
* :mod:`noise.fast.producer`: a forked helper process that makes 1/f lines ahead;
* :mod:`noise.fast.memory`: the glibc malloc policy of the ``scenesim`` command.

These modules are public inside the project (both :mod:`noise` and :mod:`scenesim`
use them) but not part of the user-facing API.
"""

__all__ = []
