use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(foo * theta.abs() + theta.powi(x) + { let u = 2.0; u % theta })]
pub struct Bad {
    pub k: f64,
}

fn main() {}
