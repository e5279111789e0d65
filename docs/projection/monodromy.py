"""Monodromy of the hinge Hessian's spectrum as a function of psi''/psi' (evidence for core/src/bending/projection.rs).

On the 8-dimensional range of Hess(theta) (eigenvalues lambda_k), H = psi'' g g^T + psi' Hess(theta) has
eigenvalues mu = psi' s with psi''/psi' = t(s) = sum_k gamma_k^2 / (s - lambda_k) (gamma: components of
g = grad theta). For random stencils this script finds the 14 branch points of t, follows the 8 roots s
around each, and prints (branch points, number of roots each loop moves, connected components of the
transposition graph). 14 loops moving 2 roots each and 1 component: the monodromy group is S_8 (not
solvable), so the eigenvalues have no closed form in psi''/psi'. Needs numpy; about 80 s.
Run: python3 docs/projection/monodromy.py > docs/projection/monodromy.txt
"""
import numpy as np
np.set_printoptions(linewidth=200, precision=4, suppress=True)
def theta(x):
    x0,x1,x2,x3 = x.reshape(4,3)
    e = x1-x0
    n0 = np.cross(e, x2-x0); n1 = np.cross(x3-x0, e)
    return np.arctan2(np.dot(np.cross(n0,n1), e/np.linalg.norm(e)), np.dot(n0,n1))
def grad_theta(x):
    x0,x1,x2,x3 = x.reshape(4,3)
    e = x1-x0; le = np.linalg.norm(e)
    n0 = np.cross(e, x2-x0); n1 = np.cross(x3-x0, e)
    A0 = np.dot(n0,n0); A1 = np.dot(n1,n1)
    # standard formula (Bridson/Wardetzky)
    g2 = -le*n0/A0; g3 = -le*n1/A1
    g0 = np.dot(x1-x2, e)/le * n0/A0 + np.dot(x1-x3,e)/le*n1/A1
    g1 = np.dot(x2-x0, e)/le * n0/A0 + np.dot(x3-x0,e)/le*n1/A1
    return np.concatenate([g0,g1,g2,g3])
def hess(x, h=1e-6):
    H = np.zeros((12,12))
    for i in range(12):
        d = np.zeros(12); d[i]=h
        H[:,i] = (grad_theta(x+d)-grad_theta(x-d))/(2*h)
    return (H+H.T)/2
def analyse(x):
    K=hess(x,1e-5); w,V=np.linalg.eigh(K)
    idx=np.argsort(np.abs(w))[4:]; lam=w[idx]; gam=(V.T@grad_theta(x))[idx]; W=gam**2
    P=np.poly1d([1.0])
    for l in lam: P=P*np.poly1d([1.0,-l])
    def Q(): # sum_k W_k prod_{j!=k}(s-l_j)
        q=np.poly1d([0.0])
        for k in range(8):
            p=np.poly1d([1.0])
            for j in range(8):
                if j!=k: p=p*np.poly1d([1.0,-lam[j]])
            q=q+W[k]*p
        return q
    Qp=Q()
    # t(s)=Q/P ; roots for given t: t*P - Q = 0
    N=Qp.deriv()*P - Qp*P.deriv()
    crit=np.roots(N.coeffs); cv=Qp(crit)/P(crit)
    def roots(t): return np.roots(np.polysub(t*P.coeffs, Qp.coeffs))
    t0=0.37+5.0j*max(1,np.max(np.abs(cv)))
    base=roots(t0)
    perms=[]
    for c in cv:
        others=[abs(c-d) for d in cv if d is not c and abs(c-d)>0]; r=0.2*min(others)
        path=list(np.linspace(t0,c+r*(t0-c)/abs(t0-c),3000))
        a0=np.angle((t0-c))
        path+= [c+r*np.exp(1j*(a0+2*np.pi*u)) for u in np.linspace(0,1,3000)[1:]]
        path+= list(np.linspace(c+r*(t0-c)/abs(t0-c),t0,3000))[1:]
        cur=base.copy()
        for t in path:
            nr=roots(t)
            new=np.empty_like(cur)
            used=set()
            for i,z in enumerate(cur):
                d=np.abs(nr-z); 
                for u in used: d[u]=np.inf
                j=int(np.argmin(d)); used.add(j); new[i]=nr[j]
            cur=new
        perm=[int(np.argmin(np.abs(base-z))) for z in cur]
        perms.append(perm)
    # cycle types, connectivity of transposition graph
    parent=list(range(8))
    def find(a):
        while parent[a]!=a: a=parent[a]
        return a
    types=[]
    for p in perms:
        moved=[i for i in range(8) if p[i]!=i]; types.append(len(moved))
        for i in moved: parent[find(i)]=find(p[i])
    comps=len(set(find(i) for i in range(8)))
    return len(cv), types, comps
rng=np.random.default_rng(7)
for trial in range(8):
    print(analyse(rng.normal(size=12)))
