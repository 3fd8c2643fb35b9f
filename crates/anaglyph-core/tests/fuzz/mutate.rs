//! The mutator: seeded, so that a run is reproducible from its seed. Each step applies
//! one to four edits to a seed input: bit flips, interesting bytes, inserted or deleted
//! runs, duplicated chunks, splices of another seed, numbers replaced by the values that
//! break size arithmetic (NaN, infinities, 2^63, 2^64 − 1, negatives), truncation; now
//! and then the input is arbitrary bytes instead.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Numbers that break parsers: non-finite, signed, overflowing, huge.
const INTERESTING_NUMBERS: [&str; 14] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "1e308",
    "-1e-308",
    "4294967296",
    "9223372036854775808",
    "18446744073709551615",
    "99999999999999999999999",
    "65536",
    "2147483648",
];
const INTERESTING_BYTES: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, b'\n', b'{', b'"'];

pub struct Mutator {
    rng: ChaCha8Rng,
}

impl Mutator {
    pub fn new(seed: u64) -> Self {
        Mutator {
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// A new input from `seeds`.
    pub fn next(&mut self, seeds: &[Vec<u8>]) -> Vec<u8> {
        if self.rng.random_ratio(1, 50) {
            let len = self.rng.random_range(0..512);
            return (0..len).map(|_| self.rng.random()).collect();
        }
        let mut input = seeds[self.rng.random_range(0..seeds.len())].clone();
        for _ in 0..self.rng.random_range(1..=4) {
            self.edit(&mut input, seeds);
        }
        input
    }

    fn edit(&mut self, input: &mut Vec<u8>, seeds: &[Vec<u8>]) {
        let len = input.len();
        let at = if len == 0 {
            0
        } else {
            self.rng.random_range(0..len)
        };
        match self.rng.random_range(0..8) {
            0 if len > 0 => input[at] ^= 1 << self.rng.random_range(0..8),
            1 if len > 0 => {
                input[at] = INTERESTING_BYTES[self.rng.random_range(0..INTERESTING_BYTES.len())]
            }
            2 => {
                let run: Vec<u8> = (0..self.rng.random_range(1..16))
                    .map(|_| self.rng.random())
                    .collect();
                input.splice(at..at, run);
            }
            3 if len > 0 => {
                let end = (at + self.rng.random_range(1..64)).min(len);
                input.drain(at..end);
            }
            4 if len > 0 => {
                let end = (at + self.rng.random_range(1..256)).min(len);
                let chunk = input[at..end].to_vec();
                let to = self.rng.random_range(0..=input.len());
                input.splice(to..to, chunk);
            }
            5 => {
                let other = &seeds[self.rng.random_range(0..seeds.len())];
                let from = self.rng.random_range(0..=other.len());
                input.truncate(at);
                input.extend_from_slice(&other[from..]);
            }
            6 => self.replace_number(input),
            _ => input.truncate(at),
        }
    }

    /// Replaces one run of ASCII digits (with its sign and point) by an interesting number.
    fn replace_number(&mut self, input: &mut Vec<u8>) {
        let starts: Vec<usize> = (0..input.len())
            .filter(|&i| input[i].is_ascii_digit() && (i == 0 || !input[i - 1].is_ascii_digit()))
            .collect();
        if starts.is_empty() {
            return;
        }
        let start = starts[self.rng.random_range(0..starts.len())];
        let end = (start..input.len())
            .find(|&i| !(input[i].is_ascii_digit() || input[i] == b'.' || input[i] == b'e'))
            .unwrap_or(input.len());
        let number = INTERESTING_NUMBERS[self.rng.random_range(0..INTERESTING_NUMBERS.len())];
        input.splice(start..end, number.bytes());
    }
}
