//! The adapter and device: which one is taken, and why none may be.

use std::fmt;

/// Which adapters a scene accepts (its `gpu` key; `"off"` makes no device at all).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpuChoice {
    /// A hardware adapter if there is one (discrete first, then integrated, then virtual);
    /// software rasterisers (lavapipe, llvmpipe) are passed over, since the CPU path is faster
    /// than they are.
    Auto,
    /// Any adapter, software ones included (what the parity tests use on a machine without a
    /// GPU).
    On,
}

/// Why no device was made.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum GpuError {
    /// No adapter the choice accepts.
    #[error("no GPU adapter{}: {found}", if *.software_refused { " (software adapters are not used with gpu = \"auto\"; gpu = \"on\" takes them)" } else { "" })]
    NoAdapter {
        /// What was found, for the log.
        found: String,
        /// Whether a software adapter was there and passed over.
        software_refused: bool,
    },
    /// The adapter would not give a device.
    #[error("the GPU adapter {adapter} gave no device: {message}")]
    Device {
        /// The adapter.
        adapter: String,
        /// Its error.
        message: String,
    },
}

/// A device and its queue.
pub struct Gpu {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
}

impl fmt::Debug for Gpu {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Gpu").field("adapter", &self.name()).finish_non_exhaustive()
    }
}

/// Preference among adapter kinds (lower first); `None`: not taken.
fn rank(kind: wgpu::DeviceType, choice: GpuChoice) -> Option<u8> {
    match kind {
        wgpu::DeviceType::DiscreteGpu => Some(0),
        wgpu::DeviceType::IntegratedGpu => Some(1),
        wgpu::DeviceType::VirtualGpu => Some(2),
        wgpu::DeviceType::Other => Some(3),
        wgpu::DeviceType::Cpu => (choice == GpuChoice::On).then_some(4),
    }
}

impl Gpu {
    /// A device on the best adapter `choice` accepts, among the backends `WGPU_BACKEND` names
    /// (by default the primary ones: Vulkan, Metal, DX12; `WGPU_BACKEND=gl` for OpenGL, which
    /// probing by default would only make noise about a missing display on a headless server).
    pub fn new(choice: GpuChoice) -> Result<Self, GpuError> {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        descriptor.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
        let backends = descriptor.backends;
        let instance = wgpu::Instance::new(descriptor);
        let adapters = futures::executor::block_on(instance.enumerate_adapters(backends));
        let mut found = Vec::new();
        let mut software_refused = false;
        let mut best: Option<(u8, usize, wgpu::Adapter)> = None;
        for (i, adapter) in adapters.into_iter().enumerate() {
            let info = adapter.get_info();
            found.push(format!("{} ({:?}, {:?})", info.name, info.device_type, info.backend));
            // Compute shaders need storage buffers in the compute stage (GL ES below 3.1 has none).
            if adapter.limits().max_storage_buffers_per_shader_stage < 8 {
                continue;
            }
            match rank(info.device_type, choice) {
                Some(r) if best.as_ref().is_none_or(|(b, _, _)| r < *b) => {
                    best = Some((r, i, adapter));
                }
                Some(_) => {}
                None => software_refused = true,
            }
        }
        let Some((_, _, adapter)) = best else {
            let found = if found.is_empty() { "none found".to_owned() } else { found.join(", ") };
            return Err(GpuError::NoAdapter { found, software_refused });
        };
        let info = adapter.get_info();
        // The adapter's own limits: the depth images of a fine view need storage buffers larger
        // than the defaults allow.
        let descriptor = wgpu::DeviceDescriptor {
            label: Some("incise"),
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) = futures::executor::block_on(adapter.request_device(&descriptor))
            .map_err(|e| GpuError::Device { adapter: info.name.clone(), message: e.to_string() })?;
        Ok(Self { device, queue, info })
    }

    /// The adapter's name, kind and backend, as a log or report names it.
    #[must_use]
    pub fn name(&self) -> String {
        format!("{} ({:?}, {:?})", self.info.name, self.info.device_type, self.info.backend)
    }

    /// Whether the adapter is a software rasteriser.
    #[must_use]
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// The largest storage buffer a binding may hold (bytes).
    pub(crate) fn max_binding(&self) -> u64 {
        self.device.limits().max_storage_buffer_binding_size
    }

    /// A compute pipeline of `entry` in the WGSL `source`.
    pub(crate) fn pipeline(&self, source: &str, entry: &str) -> wgpu::ComputePipeline {
        let module = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(entry),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: wgpu::PipelineCompilationOptions::default(),
            cache: None,
        })
    }

    /// A bind group of `buffers` at bindings `0..` of `pipeline`'s group 0.
    pub(crate) fn bind(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let numbered: Vec<(u32, &wgpu::Buffer)> =
            buffers.iter().enumerate().map(|(i, b)| (i as u32, *b)).collect();
        self.bind_some(pipeline, &numbered)
    }

    /// A bind group of `(binding, buffer)` pairs of `pipeline`'s group 0: an entry point's
    /// layout holds only the bindings it uses.
    pub(crate) fn bind_some(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .map(|&(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Reads `words` 32-bit words of `buffer` from its start (a buffer with `COPY_SRC`), through
    /// a staging buffer, waiting for the queue.
    pub(crate) fn read(&self, buffer: &wgpu::Buffer, words: usize) -> Vec<u32> {
        if words == 0 {
            return Vec::new();
        }
        let bytes = (words * 4) as u64;
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
        self.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait();
        let mapped = rx.recv().ok().and_then(Result::ok).is_some();
        assert!(mapped, "the GPU read-back buffer could not be mapped");
        let out = {
            let view = staging.slice(..).get_mapped_range().expect("a mapped read-back buffer");
            bytemuck::cast_slice::<u8, u32>(&view).to_vec()
        };
        staging.unmap();
        out
    }

    /// Runs `pipeline` once over `invocations` with `bind`, in a submission of its own.
    pub(crate) fn dispatch(
        &self,
        pipeline: &wgpu::ComputePipeline,
        bind: &wgpu::BindGroup,
        invocations: usize,
    ) {
        let mut encoder =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bind, &[]);
            pass.dispatch_workgroups(crate::buffers::groups(invocations), 1, 1);
        }
        self.queue.submit([encoder.finish()]);
    }

    /// Waits until the queue has run everything submitted.
    pub(crate) fn wait(&self) {
        // A lost device is not recoverable here; its next submission reports it.
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }
}
