"""The random numbers of rddlsim's Java policies, bit for bit.

rddlsim's `Policy` draws from commons-math3's `RandomDataGenerator`, which
wraps a `Well19937c` generator (Panneton, L'Ecuyer and Matsumoto's WELL
generator with Matsumoto-Kurita tempering); the Java client seeds it with
`setRandSeed(seed)` (0 unless the client is given another seed). This module
is that generator and the three draws rddlsim's `RandomConcurrentPolicy`
makes, so a Python policy given the same seed makes the same choices:

* `next_uniform(lo, hi)`: `RandomDataGenerator.nextUniform` (a double in
  (lo, hi), never exactly lo);
* `next_int(lo, hi)`: `RandomDataGenerator.nextInt`, both ends included
  (and, as in Java, an error when lo >= hi);
* `permute(n)`: rddlsim's `util.Permutation.permute`, a shuffle of 0..n-1.

Java's 32-bit int arithmetic is reproduced with masks: the state words are
kept as unsigned 32-bit Python ints, and where Java sign-extends an int to a
long (the seeding recurrence) the signed value is used.
"""

from __future__ import annotations

_MASK32 = 0xFFFFFFFF
_MASK64 = 0xFFFFFFFFFFFFFFFF

# Well19937c's parameters: k = 19937 bits in r = 624 words of 32 bits.
_R = 624
_M1 = 70
_M2 = 179
_M3 = 449


def _signed32(x: int) -> int:
    x &= _MASK32
    return x - (1 << 32) if x & 0x80000000 else x


class Well19937c:
    """commons-math3's `Well19937c`: `set_seed(long)` and `next(bits)`."""

    def __init__(self, seed: int = 0) -> None:
        self._v = [0] * _R
        self._index = 0
        # the index tables of AbstractWell, precomputed as Java does
        self._rm1 = [(j + _R - 1) % _R for j in range(_R)]
        self._rm2 = [(j + _R - 2) % _R for j in range(_R)]
        self._i1 = [(j + _M1) % _R for j in range(_R)]
        self._i2 = [(j + _M2) % _R for j in range(_R)]
        self._i3 = [(j + _M3) % _R for j in range(_R)]
        self.set_seed(seed)

    def set_seed(self, seed: int) -> None:
        """`setSeed(long)`: the two halves of the long seed the pool, the
        rest follows Knuth's recurrence on sign-extended words."""
        seed &= _MASK64
        words = [_signed32(seed >> 32), _signed32(seed)]
        v = words + [0] * (_R - 2)
        for i in range(2, _R):
            prev = v[i - 2]  # a Java int widened to a long: sign-extended
            v[i] = _signed32(1812433253 * (prev ^ (prev >> 30)) + i)
        self._v = [x & _MASK32 for x in v]
        self._index = 0

    def next(self, bits: int) -> int:
        """The next `bits` (1..32) random bits, as a non-negative int."""
        v = self._v
        i = self._index
        rm1 = self._rm1[i]
        rm2 = self._rm2[i]
        v0 = v[i]
        vm1 = v[self._i1[i]]
        vm2 = v[self._i2[i]]
        vm3 = v[self._i3[i]]
        z0 = (0x80000000 & v[rm1]) ^ (0x7FFFFFFF & v[rm2])
        z1 = (v0 ^ ((v0 << 25) & _MASK32)) ^ (vm1 ^ (vm1 >> 27))
        z2 = (vm2 >> 9) ^ (vm3 ^ (vm3 >> 1))
        z3 = z1 ^ z2
        z4 = z0 ^ (z1 ^ ((z1 << 9) & _MASK32)) ^ (z2 ^ ((z2 << 21) & _MASK32)) ^ (z3 ^ (z3 >> 21))
        v[i] = z3
        v[rm1] = z4
        v[rm2] &= 0x80000000
        self._index = rm1
        # Matsumoto-Kurita tempering
        z4 ^= (z4 << 7) & 0xE46E1700
        z4 ^= (z4 << 15) & 0x9B868000
        return (z4 & _MASK32) >> (32 - bits)

    def next_double(self) -> float:
        """`BitsStreamGenerator.nextDouble`: 52 random bits in [0, 1)."""
        high = self.next(26) << 26
        low = self.next(26)
        return (high | low) * 2.0**-52

    def next_int(self, n: int) -> int:
        """`BitsStreamGenerator.nextInt(n)`: uniform in 0..n-1."""
        if n <= 0:
            raise ValueError(f"bound must be strictly positive, got {n}")
        if n & -n == n:  # a power of two: the high bits
            return (n * self.next(31)) >> 31
        while True:
            bits = self.next(31)
            val = bits % n
            # Java's int overflow makes this negative for the last partial block
            if _signed32(bits - val + (n - 1)) >= 0:
                return val


class RandomDataGenerator:
    """The part of commons-math3's `RandomDataGenerator` rddlsim's policies
    use, over a `Well19937c` seeded as `Policy.setRandSeed(seed)` seeds it."""

    def __init__(self, seed: int = 0) -> None:
        self.generator = Well19937c(seed)

    def next_uniform(self, lower: float, upper: float) -> float:
        """`nextUniform(lower, upper)`: a double in (lower, upper)."""
        if lower >= upper:
            raise ValueError(f"lower bound {lower} must be below the upper bound {upper}")
        u = self.generator.next_double()
        while u <= 0.0:
            u = self.generator.next_double()
        # the same operations in the same order as Java, for the same last bit
        return u * upper + (1.0 - u) * lower

    def next_int(self, lower: int, upper: int) -> int:
        """`nextInt(lower, upper)`: an int in lower..upper, both included.
        Raises ValueError when lower >= upper, as Java raises
        NumberIsTooLargeException."""
        if lower >= upper:
            raise ValueError(f"lower bound {lower} must be below the upper bound {upper}")
        span = upper - lower + 1
        if span > 0x7FFFFFFF:  # wider than a positive Java int: rejection, as Java
            while True:
                r = _signed32(self.generator.next(32))
                if lower <= r <= upper:
                    return r
        return lower + self.generator.next_int(span)

    def permute(self, n: int) -> list[int]:
        """rddlsim's `util.Permutation.permute(n, rand)`: 0..n-1 shuffled by
        swapping position i with a position drawn from 0..i."""
        a = list(range(n))
        for i in range(1, n):
            r = self.next_int(0, i)
            a[r], a[i] = a[i], a[r]
        return a
