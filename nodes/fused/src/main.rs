//! dora node: several stages in one process (see the library, `neuspike_fused::run`).

fn main() -> std::process::ExitCode {
    neuspike_runtime::init_logging();
    neuspike_runtime::exit_code(neuspike_fused::run())
}
