use hinge_core::HingeEnergy;

#[derive(HingeEnergy)]
#[psi(k * stiffness * (theta - theta_bar).powi(2))]
pub struct Bad {
    pub k: f64,
}

fn main() {}
