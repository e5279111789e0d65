use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(k * (1.5 + theta.cos()).powf(theta))]
pub struct Bad {
    pub k: f64,
}

fn main() {}
