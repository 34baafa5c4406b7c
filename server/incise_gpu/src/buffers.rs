//! Storage buffers that grow as their contents do, and the packing of values into 32-bit words.

use crate::context::Gpu;

/// A storage buffer of 32-bit words, reallocated (larger) only when its contents outgrow it.
pub(crate) struct Words {
    label: &'static str,
    buffer: wgpu::Buffer,
    /// Words it holds room for.
    capacity: usize,
}

impl Words {
    pub(crate) fn new(gpu: &Gpu, label: &'static str, capacity: usize) -> Self {
        let capacity = capacity.max(4);
        Self { label, buffer: storage(gpu, label, capacity), capacity }
    }

    /// Makes room for `words` words; `true` when the buffer was replaced (its contents lost).
    pub(crate) fn reserve(&mut self, gpu: &Gpu, words: usize) -> bool {
        if words <= self.capacity {
            return false;
        }
        let capacity = words.next_power_of_two();
        self.buffer = storage(gpu, self.label, capacity);
        self.capacity = capacity;
        true
    }

    /// Writes `data` at word `offset` (room must have been made).
    pub(crate) fn write(&self, gpu: &Gpu, offset: usize, data: &[u32]) {
        if !data.is_empty() {
            gpu.queue.write_buffer(&self.buffer, (offset * 4) as u64, bytemuck::cast_slice(data));
        }
    }

    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

fn storage(gpu: &Gpu, label: &str, words: usize) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (words * 4) as u64,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// A storage buffer of fixed-size records that mirrors a CPU table: setting the table sends only
/// the runs of records that differ from what the device holds.
pub(crate) struct Mirrored {
    words: Words,
    /// What the device holds, word for word.
    shadow: Vec<u32>,
    /// Words per record.
    stride: usize,
}

impl Mirrored {
    pub(crate) fn new(gpu: &Gpu, label: &'static str, stride: usize) -> Self {
        Self { words: Words::new(gpu, label, stride), shadow: Vec::new(), stride }
    }

    /// Makes the device's records `new` (a whole number of records); returns how many were sent.
    pub(crate) fn set(&mut self, gpu: &Gpu, new: Vec<u32>) -> usize {
        let stride = self.stride;
        let count = new.len() / stride;
        let replaced = self.words.reserve(gpu, new.len());
        let same = |shadow: &[u32], r: usize| {
            !replaced
                && shadow.get(r * stride..(r + 1) * stride)
                    == Some(&new[r * stride..(r + 1) * stride])
        };
        let (mut sent, mut r) = (0, 0);
        while r < count {
            if same(&self.shadow, r) {
                r += 1;
                continue;
            }
            let start = r;
            while r < count && !same(&self.shadow, r) {
                r += 1;
            }
            self.words.write(gpu, start * stride, &new[start * stride..r * stride]);
            sent += r - start;
        }
        self.shadow = new;
        sent
    }

    /// Records held.
    pub(crate) fn len(&self) -> usize {
        self.shadow.len() / self.stride
    }

    /// Record `r`'s words.
    pub(crate) fn record(&self, r: usize) -> &[u32] {
        &self.shadow[r * self.stride..(r + 1) * self.stride]
    }

    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        self.words.buffer()
    }
}

/// A uniform buffer of `words` 32-bit words.
pub(crate) fn uniform(gpu: &Gpu, label: &str, words: &[u32]) -> wgpu::Buffer {
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (words.len().max(4).next_multiple_of(4) * 4) as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    gpu.queue.write_buffer(&buffer, 0, bytemuck::cast_slice(words));
    buffer
}

/// `f32` bits of `x`.
pub(crate) fn f(x: f64) -> u32 {
    (x as f32).to_bits()
}

/// Positions as packed `f32` triples.
pub(crate) fn packed(points: &[[f64; 3]]) -> Vec<u32> {
    points.iter().flat_map(|p| p.map(f)).collect()
}

/// Packed `f32` triples back as positions.
pub(crate) fn unpacked(words: &[u32]) -> Vec<[f64; 3]> {
    words.chunks_exact(3).map(|c| [0, 1, 2].map(|k| f64::from(f32::from_bits(c[k])))).collect()
}

/// Workgroups of 64 for `n` invocations.
pub(crate) fn groups(n: usize) -> u32 {
    n.div_ceil(64).max(1) as u32
}
